"""The server's work pool and its fair queue: kinds of work and clients take turns, none starves,
a flood of one kind cannot lock the others out of the queue; phone-stream pushes join the batch
waiting for a worker (no timing: jobs are gated by events)."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
from vispeech.alignment.phones import Phone  # noqa: E402
from vispeech.serve import ServeConfig, SpeechService, open_phone_stream  # noqa: E402
from vispeech.serve.pool import TURN_WEIGHT, Busy, Cancelled, FairQueue, WorkPool  # noqa: E402
from vispeech.turns import give_turn  # noqa: E402

FLOODS = ("text", "upload", "chat")


def take(queue: FairQueue, seconds: float) -> tuple[str, str, object]:
    """Pop the next job and say it took ``seconds`` (charged beyond its weight of 0)."""
    kind, client, job = queue.pop()
    queue.done(kind, client, seconds)
    return kind, client, job


def flooded() -> FairQueue:
    """A queue holding 100 jobs of each of :data:`FLOODS`, from 10 clients each."""
    queue: FairQueue = FairQueue()
    for kind in FLOODS:
        for k in range(100):
            queue.push(kind, f"{kind}-{k % 10}", f"{kind} {k}")
    return queue


def test_a_sequential_kind_is_taken_within_a_turn_of_each_other_kind():
    """A phone stream's pieces, each queued once the one before has run, beside three kinds of work
    that always have 100 jobs waiting and take ten times as long: each piece is taken within one
    job of each of those kinds."""
    queue = flooded()
    for _ in range(5):  # the floods have run a while
        take(queue, 0.5)
    for piece in range(20):
        queue.push("phones", "phone streams", piece)
        taken = []
        while len(taken) <= len(FLOODS) and "phones" not in taken:
            kind, client, job = queue.pop()
            queue.done(kind, client, 0.05 if kind == "phones" else 0.5)
            taken.append(kind)
            if kind != "phones":
                queue.push(kind, client, "more")  # the flood never ends
        assert taken[-1] == "phones" and job == piece, taken


def test_clients_of_a_kind_take_turns_and_keep_their_own_order():
    queue: FairQueue = FairQueue()
    for k in range(50):
        queue.push("speak", "heavy", k)
    assert take(queue, 1.0)[2] == 0
    queue.push("speak", "light", "a")
    queue.push("speak", "light", "b")
    taken = [take(queue, 0.1)[1:] for _ in range(4)]
    assert taken == [("light", "a"), ("light", "b"), ("heavy", 1), ("heavy", 2)]


def test_a_client_that_had_more_than_its_share_waits_and_an_idle_one_saves_nothing():
    queue: FairQueue = FairQueue()
    queue.push("speak", "heavy", "h0")
    take(queue, 5.0)  # heavy had 5 s, then nothing waits
    for k in range(10):
        queue.push("speak", "busy", f"b{k}")
    take(queue, 1.0)
    queue.push("speak", "heavy", "h1")
    order = [take(queue, 1.0)[2] for _ in range(6)]
    assert order == ["b1", "b2", "b3", "b4", "b5", "h1"]  # busy catches up with heavy's 5 s first
    queue.push("speak", "idle", "i0")
    queue.push("speak", "idle", "i1")
    queue.push("speak", "idle", "i2")
    # idle waited 7 s but starts at the clock: it alternates with busy, it does not run three in a row
    assert [take(queue, 1.0)[1] for _ in range(4)] == ["idle", "busy", "idle", "busy"]


def test_a_new_session_goes_before_the_next_jobs_of_its_clients_older_ones():
    """Streams of one address (one client): each session's jobs in order, and the first job of a
    session that comes later goes before the next jobs of those that have had one."""
    queue: FairQueue = FairQueue()
    for k in range(3):
        queue.push("text", "10.0.0.1", f"s{k} first", 0.01, session=f"s{k}")
    kind, client, job = queue.pop()
    assert job == "s0 first"
    queue.done(kind, client, 0.0, session="s0")
    queue.push("text", "10.0.0.1", "s0 second", 0.01, session="s0")
    queue.push("text", "10.0.0.1", "s3 first", 0.01, session="s3")  # a session that comes later
    order = []
    while len(queue):
        job = queue.pop()[2]
        queue.done("text", "10.0.0.1", 0.0, session=job.split()[0])
        order.append(job)
    assert order == ["s1 first", "s2 first", "s3 first", "s0 second"]


def test_the_pool_is_full_by_the_work_waiting_and_by_a_count_of_jobs():
    async def scenario():
        pool = WorkPool(workers=1, max_queue=50, max_wait=1.0)
        started, gate = threading.Event(), threading.Event()

        def job(name):
            if name == "gate":
                started.set()
                gate.wait(30)
            return name

        blocker = asyncio.ensure_future(pool.run("other", "x", job, "gate"))
        await asyncio.to_thread(started.wait, 30)
        heavy = [asyncio.ensure_future(pool.run("upload", "u", job, f"u{k}", weight=0.3)) for k in range(4)]
        await asyncio.sleep(0)  # 1.2 s of work waits, past max_wait for the one worker
        with pytest.raises(Busy, match="4 jobs waiting"):
            await pool.run("upload", "u", job, "refused", weight=0.001)
        # many small jobs of another kind fit beside, up to its share of the count (50 over 2 kinds)
        light = [asyncio.ensure_future(pool.run("text", f"t{k}", job, f"t{k}", weight=0.001)) for k in range(25)]
        await asyncio.sleep(0)
        with pytest.raises(Busy):
            await pool.run("text", "t", job, "refused", weight=0.001)
        gate.set()
        done = await asyncio.gather(blocker, *heavy, *light)
        assert "refused" not in done and len(done) == 30
        pool.close()

    asyncio.run(scenario())


def test_an_empty_queue_pops_nothing():
    queue: FairQueue = FairQueue()
    assert len(queue) == 0
    with pytest.raises(IndexError):
        queue.pop()


def test_the_pool_takes_kinds_in_turn_and_refuses_only_a_kind_over_its_share():
    async def scenario():
        pool = WorkPool(workers=1, max_queue=4)
        started, gate, order = threading.Event(), threading.Event(), []

        def job(name):
            if name == "gate":
                started.set()
                gate.wait(30)
            order.append(name)
            return name

        blocker = asyncio.ensure_future(pool.run("other", "x", job, "gate"))
        await asyncio.to_thread(started.wait, 30)  # the worker holds the gate job
        texts = [asyncio.ensure_future(pool.run("text", f"t{k}", job, f"t{k}")) for k in range(4)]
        await asyncio.sleep(0)  # queued: the queue is full
        with pytest.raises(Busy):
            await pool.run("text", "t9", job, "refused")  # text holds 4 of 4
        # phones may hold their share of the queue, 4 over 2 kinds waiting
        phones = [asyncio.ensure_future(pool.run("phones", "p", job, f"p{k}")) for k in range(2)]
        await asyncio.sleep(0)
        with pytest.raises(Busy):
            await pool.run("phones", "p", job, "refused")
        gate.set()
        await asyncio.gather(blocker, *phones, *texts)
        assert order[:3] == ["gate", "t0", "p0"] and sorted(order[3:]) == ["p1", "t1", "t2", "t3"]
        cancelled = threading.Event()
        cancelled.set()
        with pytest.raises(Cancelled):
            await pool.run("text", "gone", job, "never", cancelled=cancelled)
        assert "never" not in order and "refused" not in order
        pool.close()

    asyncio.run(scenario())


def test_pushes_made_while_the_batch_waits_for_a_worker_join_it():
    """With the only worker busy, pushes of three sessions made one after another go as one batch;
    two pushes of one session go in two."""
    service = SpeechService(ServeConfig(cache=":memory:", workers=1, default_model="baseline", stream_model="baseline"))
    model = service.models["baseline"]
    phones = [Phone("AA1", 0.1 * k, 0.1 * (k + 1)) for k in range(8)]
    streams = [open_phone_stream(model, "en") for _ in range(3)]

    async def pushed_while_busy(pushes: list[tuple]) -> list:
        started, gate = threading.Event(), threading.Event()

        def hold():
            started.set()
            gate.wait(30)

        blocker = asyncio.ensure_future(service.pool.run("text", "someone", hold))
        await asyncio.to_thread(started.wait, 30)
        futures = []
        for stream, some in pushes:
            futures.append(asyncio.ensure_future(service.pushes.push(stream, some, service.calibration, 0.1)))
            await asyncio.sleep(0)  # each in a turn of the loop of its own
        gate.set()
        await blocker
        return await asyncio.gather(*futures)

    first = asyncio.run(pushed_while_busy([(stream, phones[:4]) for stream in streams]))
    assert (service.pushes.batches, service.pushes.pushes, service.pushes.largest) == (1, 3, 3)
    second = asyncio.run(pushed_while_busy([(streams[0], phones[4:6]), (streams[0], phones[6:])]))
    assert (service.pushes.batches, service.pushes.pushes) == (3, 5)
    assert all(isinstance(result, str) for result in first + second)
    service.pool.close()


def _spin(seconds: float) -> None:
    """Hold the thread for ``seconds`` of work (a sleep: the pool counts time, not cycles)."""
    time.sleep(seconds)


def test_a_long_job_lets_the_short_jobs_waiting_run_in_its_turns():
    """A long job that gives turns between its pieces: the short jobs queued behind it run at its
    next turn, on its thread, in the queue's order; the time lent stays within the job's own, so
    a short job that takes longer than a piece lets the long job go on for pieces before the next."""

    async def scenario():
        pool = WorkPool(workers=1, max_queue=16)
        started, queued, order, threads = threading.Event(), threading.Event(), [], set()

        def long_job(pieces, piece):
            started.set()
            queued.wait(30)
            for k in range(pieces):
                _spin(piece)
                order.append(f"long{k}")
                threads.add(threading.get_ident())
                give_turn()
            return "long"

        def short(name, seconds):
            _spin(seconds)
            order.append(name)
            threads.add(threading.get_ident())
            return name

        async def beside(pieces: int, piece: float, client: str, seconds: float) -> list:
            """A long job of ``pieces`` of ``piece`` s and three short jobs of ``seconds`` queued behind it."""
            order.clear()
            started.clear()
            queued.clear()
            long = asyncio.ensure_future(pool.run("upload", "a", long_job, pieces, piece, weight=20.0))
            await asyncio.to_thread(started.wait, 30)
            shorts = [asyncio.ensure_future(pool.run("text", f"{client}{k}", short, f"s{k}", seconds, weight=0.01))
                      for k in range(3)]
            await asyncio.sleep(0)
            queued.set()
            return await asyncio.gather(long, *shorts)

        # pieces of 20 ms, three short jobs of 5 ms: all three go at the first turn
        assert await beside(6, 0.02, "c", 0.005) == ["long", "s0", "s1", "s2"]
        assert order[:5] == ["long0", "s0", "s1", "s2", "long1"] and len(threads) == 1, order
        # pieces of 10 ms, short jobs of 30 ms: after each, the long job has its own time back first
        await beside(20, 0.01, "d", 0.03)
        at = {name: order.index(name) for name in ("s0", "s1", "s2", "long19")}
        assert order[:2] == ["long0", "s0"] and at["s1"] - at["s0"] > 2 and at["s2"] - at["s1"] > 2, order
        assert at["s2"] < at["long19"], order  # each short job ran within the long one
        pool.close()

    asyncio.run(scenario())


def test_turns_pass_over_heavy_jobs_and_a_job_run_in_a_turn_gives_none():
    """A waiting job estimated above ``TURN_WEIGHT`` (another long job) waits for the long job's end;
    a short job run in a turn that gives turns itself runs nobody else; its error reaches its own
    caller and the long job goes on."""

    async def scenario():
        pool = WorkPool(workers=1, max_queue=16)
        started, queued, order = threading.Event(), threading.Event(), []

        def long_job():
            started.set()
            queued.wait(30)
            for k in range(3):
                _spin(0.02)
                order.append(f"long{k}")
                give_turn()
            return "long"

        def job(name, fail=False):
            order.append(f"{name} begins")
            give_turn()
            order.append(f"{name} ends")
            if fail:
                raise ValueError("bad input")
            return name

        long = asyncio.ensure_future(pool.run("upload", "a", long_job, weight=20.0))
        await asyncio.to_thread(started.wait, 30)
        heavy = asyncio.ensure_future(pool.run("upload", "b", job, "heavy", weight=TURN_WEIGHT + 1))
        failing = asyncio.ensure_future(pool.run("text", "c", job, "a", True, weight=0.01))
        light = asyncio.ensure_future(pool.run("text", "d", job, "b", weight=0.01))
        await asyncio.sleep(0)
        queued.set()
        assert await long == "long" and await light == "b" and await heavy == "heavy"
        with pytest.raises(ValueError, match="bad input"):
            await failing
        assert order == [
            "long0", "a begins", "a ends", "b begins", "b ends", "long1", "long2", "heavy begins", "heavy ends"
        ], order  # fmt: skip
        pool.close()

    asyncio.run(scenario())


def test_only_a_long_job_lends_its_worker_and_only_when_no_other_is_idle():
    """Found by review: every job gave turns, so a 20-ms live-audio push ran a queued speech job
    before its own work (the job the fair queue took first ended last); a long job lent its turns
    though another worker was idle; and the long job's kind was charged the time it lent too."""

    async def scenario():
        pool = WorkPool(workers=1, max_queue=16)
        started, queued, order = threading.Event(), threading.Event(), []

        def job(name, pieces=1, piece=0.01):
            started.set()
            queued.wait(30)
            for _ in range(pieces):
                give_turn()
                _spin(piece)
            order.append((name, threading.get_ident()))
            return name

        short = asyncio.ensure_future(pool.run("listen", "a", job, "short", weight=0.01))
        await asyncio.to_thread(started.wait, 30)
        behind = asyncio.ensure_future(pool.run("text", "b", job, "behind", 1, 0.05, weight=0.2))
        await asyncio.sleep(0)
        queued.set()
        await asyncio.gather(short, behind)
        assert [name for name, _ in order] == ["short", "behind"]  # the short job gave no turn

        order.clear()
        started.clear()
        queued.clear()
        long = asyncio.ensure_future(pool.run("upload", "a", job, "long", 10, 0.02, weight=20.0))
        await asyncio.to_thread(started.wait, 30)
        lent = [asyncio.ensure_future(pool.run("text", f"c{k}", job, f"lent{k}", 1, 0.02, weight=0.01))
                for k in range(3)]
        await asyncio.sleep(0)
        queued.set()
        await asyncio.gather(long, *lent)
        assert [name for name, _ in order][-1] == "long"
        kinds = pool._queue._root.children  # what each kind was charged: the long job its own 0.2 s only
        assert kinds["upload"].time < 0.2 + 0.06, kinds["upload"].time
        pool.close()

        pool = WorkPool(workers=2, max_queue=16)  # an idle worker takes the short jobs itself
        order.clear()
        started.clear()
        queued.clear()
        long = asyncio.ensure_future(pool.run("upload", "a", job, "long", 10, 0.02, weight=20.0))
        await asyncio.to_thread(started.wait, 30)
        queued.set()
        await asyncio.sleep(0.05)
        shorts = [await pool.run("text", f"c{k}", job, f"s{k}", 1, 0.001, weight=0.01) for k in range(3)]
        await long
        threads = dict(order)
        assert shorts == ["s0", "s1", "s2"] and all(threads[s] != threads["long"] for s in shorts), order
        pool.close()

    asyncio.run(scenario())


def test_a_process_forked_inside_a_turn_taking_job_takes_no_turns():
    """A native worker forked while a long job ran (the pool started or restarted from inside it)
    kept the turn, bound to its copy of the server's queue: review found a queued job run twice,
    once in the espeak-ng worker. A forked child forgets the turn."""
    import os

    from vispeech.turns import taking_turns

    calls = []
    with taking_turns(lambda: calls.append(os.getpid())):
        give_turn()
        reader, writer = os.pipe()
        pid = os.fork()
        if pid == 0:  # the child: a turn here must do nothing
            give_turn()
            os.write(writer, str(len(calls)).encode())
            os._exit(0)
        os.close(writer)
        seen = os.read(reader, 16)
        os.waitpid(pid, 0)
    assert seen == b"1" and calls == [os.getpid()]


def test_a_long_job_does_not_lend_while_a_thread_is_idle_beside_one_lending():
    """Found by the second review: "no idle worker" was told from the running jobs, and a job one
    long job runs in its turn counted as a busy thread: with three workers, two long jobs (one
    lending) and the third thread idle, the other long job still took short jobs in its turns."""

    async def scenario():
        pool = WorkPool(workers=3, max_queue=64)
        stop, release_c, release_b, threads = threading.Event(), threading.Event(), threading.Event(), {}

        def long(name):
            threads[name] = threading.get_ident()
            while not stop.is_set():
                give_turn()
                time.sleep(0.0005)
            return name

        def blocker(name, event):
            threads[name] = threading.get_ident()
            event.wait(10)
            return name

        def short(name):
            threads[name] = threading.get_ident()
            return name

        longs = [asyncio.ensure_future(pool.run("upload", k, long, k, weight=20.0)) for k in ("L1", "L2")]
        c = asyncio.ensure_future(pool.run("text", "c", blocker, "Sc", release_c, weight=0.01))
        await asyncio.sleep(0.1)
        b = asyncio.ensure_future(pool.run("text", "d", blocker, "Sb", release_b, weight=0.01))  # lent by L1 or L2
        await asyncio.sleep(0.1)
        release_c.set()
        await c  # its thread is idle now
        await asyncio.sleep(0.05)
        idle = threads["Sc"]
        ran = []
        for k in range(50):
            await pool.run("text", "e", short, f"n{k}", weight=0.01)
            ran.append(threads[f"n{k}"])
            await asyncio.sleep(0.002)
        release_b.set()
        stop.set()
        await asyncio.gather(b, *longs)
        pool.close()
        assert ran == [idle] * 50, sum(t != idle for t in ran)

    asyncio.run(scenario())
