"""The bounded pool of worker threads that runs the server's CPU-heavy work, fair between kinds of
work and between clients."""

from __future__ import annotations

import asyncio
import itertools
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from functools import partial
from typing import Generic, TypeVar

from vispeech.turns import taking_turns

T = TypeVar("T")

MAX_CLIENTS = 10_000
"""Clients a kind remembers the worker time of; past that the idle ones are forgotten."""
TURN_WEIGHT = 1.0
"""Estimated seconds of the heaviest waiting job that a long job lets run in its turns
(:meth:`WorkPool._turn`): a speech request, a stream's clause or piece, not another long job."""


class Busy(Exception):
    """The work queue is full (HTTP 503 with ``Retry-After``, or a stream error)."""

    retry_after = 1


class Cancelled(Exception):
    """The job's client went away before it started: it never ran (HTTP 503 with ``Retry-After``)."""

    retry_after = 1


class _Job:
    __slots__ = ("abandoned", "args", "cancelled", "fn", "future", "key", "kind", "loop", "session", "weight")

    def __init__(self, fn, args, kind, key, session, weight, future, loop, cancelled) -> None:
        self.fn, self.args, self.kind, self.key, self.session, self.weight = fn, args, kind, key, session, weight
        self.future, self.loop, self.cancelled = future, loop, cancelled
        self.abandoned = False


def _settle(future: asyncio.Future, result, error: BaseException | None) -> None:
    if future.done():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


class _Flow:
    """A node of the queue's tree: the root, a kind of work, a client of a kind, or a session of a
    client (whose ``jobs`` wait in order)."""

    __slots__ = ("children", "clock", "jobs", "ready", "running", "since", "time", "waiting", "work")

    def __init__(self) -> None:
        self.time = 0.0  # virtual time: worker seconds had, caught up to its parent's clock when it comes back
        self.since = 0  # when it last came back (ties: the one waiting longer first)
        self.clock = 0.0  # the virtual time of the last of its children taken
        self.waiting = 0  # jobs waiting in it
        self.work = 0.0  # their estimated worker seconds
        self.running = 0  # jobs taken from it, not done
        self.children: dict[str, _Flow] = {}
        self.ready: dict[str, _Flow] = {}  # the children with jobs waiting
        self.jobs: deque = deque()  # a session's (job, weight), in order


def _first(flows: Iterable[tuple[str, _Flow]]) -> tuple[str, _Flow]:
    return min(flows, key=lambda flow: (flow[1].time, flow[1].since))


class FairQueue(Generic[T]):
    """Jobs waiting for a worker, taken fairly: kinds of work in turn, within a kind its clients in
    turn, within a client its sessions in turn, a session's own jobs in order.

    Start-time fair queueing at each level: each kind of work (``"text"``, ``"phones"``, ...), each
    client within it and each session within that has a virtual time, the worker seconds it has
    had: a job's estimated ``weight`` when :meth:`pop` takes it, the rest when :meth:`done` says
    what it took. :meth:`pop` takes from the kind with the least, in it from the client with the
    least, and from that client's session with the least. One that comes back after having
    nothing waiting starts at the virtual time of the last one taken beside it (its parent's
    ``clock``), so an idle time is not saved up, while one that had more than its share lately
    waits until the others have caught up: a new session's first job goes before the next jobs of
    its client's older sessions. A kind with jobs waiting is taken within as many pops as there
    are other kinds waiting, however many jobs they hold (as long as each job taken costs some
    time); a client likewise within its kind, a session within its client.
    """

    def __init__(self) -> None:
        self._root = _Flow()
        self._turns = itertools.count()

    def __len__(self) -> int:
        return self._root.waiting

    @property
    def work(self) -> float:
        """The estimated worker seconds of the jobs waiting."""
        return self._root.work

    def work_of(self, kind: str) -> float:
        """The estimated worker seconds of the jobs of ``kind`` waiting."""
        flow = self._root.children.get(kind)
        return 0.0 if flow is None else flow.work

    def waiting(self, kind: str) -> int:
        """How many jobs of ``kind`` wait."""
        flow = self._root.children.get(kind)
        return 0 if flow is None else flow.waiting

    @property
    def kinds_waiting(self) -> int:
        """How many kinds of work have jobs waiting."""
        return len(self._root.ready)

    def push(self, kind: str, client: str, job: T, weight: float = 0.0, session: str = "") -> None:
        """Queue ``job`` of ``client``'s ``session``, of ``kind``, estimated to take ``weight`` worker seconds."""
        weight = max(0.0, weight)
        node = self._root
        for name in (kind, client, session):
            child = node.children.get(name)
            if child is None:
                child = node.children[name] = _Flow()
            if not child.waiting:
                child.time, child.since = max(child.time, node.clock), next(self._turns)
                node.ready[name] = child
            node.waiting += 1
            node.work += weight
            node = child
        node.waiting += 1
        node.work += weight
        node.jobs.append((job, weight))

    def _next(self) -> list[tuple[_Flow, str, _Flow]]:
        """The path from the root to the session whose first job :meth:`pop` takes next."""
        if not self._root.waiting:
            raise IndexError("no job waits")
        path: list[tuple[_Flow, str, _Flow]] = []
        node = self._root
        while node.ready:
            name, child = _first(node.ready.items())
            path.append((node, name, child))
            node = child
        return path

    def next_weight(self) -> float:
        """The estimated weight of the job :meth:`pop` would take now (:exc:`IndexError` when none waits)."""
        return self._next()[-1][2].jobs[0][1]

    def pop(self) -> tuple[str, str, T]:
        """The next job to run, with its kind and client (:exc:`IndexError` when none waits); its
        weight is charged to them until :meth:`done`."""
        path = self._next()
        for node, _, child in path:
            node.clock = max(node.clock, child.time)
        node = path[-1][2]
        job, weight = node.jobs.popleft()
        for flow in (self._root, *(child for _, _, child in path)):
            flow.waiting -= 1
            flow.work = flow.work - weight if flow.waiting else 0.0  # no rounding error left over
        for parent, name, child in path:
            if not child.waiting:
                del parent.ready[name]
            child.running += 1
            child.time += weight
        return path[0][1], path[1][1], job

    def done(self, kind: str, client: str, seconds: float, session: str = "") -> None:
        """A job :meth:`pop` took for ``client``'s ``session`` took ``seconds`` more than its weight
        (negative: less), charged to its kind, client and session."""
        path: list[tuple[_Flow, str, _Flow]] = []
        node = self._root
        for name in (kind, client, session):
            child = node.children[name]
            child.time += seconds
            child.running -= 1
            path.append((node, name, child))
            node = child
        for parent, name, child in reversed(path[1:]):  # kinds stay
            if not child.waiting and not child.running and child.time <= parent.clock:
                del parent.children[name]  # it would come back at the clock: nothing to remember
            elif len(parent.children) > MAX_CLIENTS:  # forget what the idle ones had
                parent.children = {n: c for n, c in parent.children.items() if c.waiting or c.running}


class WorkPool:
    """A bounded pool of worker threads for the CPU-heavy work, with a bounded, fair queue.

    ``await pool.run(kind, key, fn, *args)`` runs ``fn(*args)`` on one of ``workers`` threads
    and returns its result. Waiting jobs are taken from a :class:`FairQueue`: kinds of work
    (text streams, phone streams, uploads, chats, ...) in turn by the worker time each has had,
    within a kind its clients (``key``, the IP address) likewise, within a client its sessions
    (``session``: a stream connection), a session's own jobs in order; so no kind starves beside
    another's flood, and a new or light client or session goes before a heavy one's next job.

    The queue is full when its jobs' estimated work passes ``max_wait`` seconds for each worker
    (what a job queued last would wait), or when ``max_queue`` jobs wait (each costs memory,
    whatever its weight). A job that finds it full is refused at once (:class:`Busy`) unless its
    kind holds less than its share of the work and of the jobs (over the kinds waiting): a flood
    of one kind cannot lock the others out. A job whose ``cancelled`` event is set, or whose
    caller stopped waiting, is dropped unrun. A long job that gives turns between its pieces
    (:func:`vispeech.turns.give_turn`) lets the light jobs waiting run on its thread (:meth:`_turn`).
    """

    def __init__(self, workers: int, max_queue: int, max_wait: float = math.inf) -> None:
        if workers < 1 or max_queue < 1 or not max_wait > 0:
            raise ValueError("workers and max_queue must be at least 1, max_wait more than 0")
        self.workers = workers
        self.max_queue = max_queue
        self.max_wait = max_wait
        self._queue: FairQueue[_Job] = FairQueue()
        self._cond = threading.Condition()
        self._threads: list[threading.Thread] = []
        self._closed = False
        self.running = 0
        self._lent = 0  # of them, the jobs a long job runs in its turns (on its own, busy, thread)

    @property
    def queued(self) -> int:
        return len(self._queue)

    def _start(self) -> None:
        while len(self._threads) < self.workers:
            thread = threading.Thread(target=self._work, name=f"vispeech-work-{len(self._threads)}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def _full(self, kind: str) -> bool:
        queue = self._queue
        budget = self.max_wait * self.workers
        if len(queue) < self.max_queue and queue.work < budget:
            return False
        mine = queue.waiting(kind)
        kinds = queue.kinds_waiting + (0 if mine else 1)
        return mine >= self.max_queue // kinds or queue.work_of(kind) >= budget / kinds

    async def run(
        self,
        kind: str,
        key: str,
        fn: Callable,
        *args,
        cancelled: threading.Event | None = None,
        weight: float = 0.0,
        session: str = "",
    ):
        """``fn(*args)`` on a worker thread, a job of client ``key``'s ``session`` of ``kind``,
        estimated to take ``weight`` seconds; :class:`Busy` when the queue is full,
        :class:`Cancelled` when ``cancelled`` was set before it started."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        job = _Job(fn, args, kind, key, session, max(0.0, weight), future, loop, cancelled)
        with self._cond:
            if self._closed:
                raise Busy("the server is shutting down")
            if self._full(kind):
                queue = self._queue
                raise Busy(f"server busy: {len(queue)} jobs waiting ({queue.work:.1f} s of work), try again later")
            self._start()
            self._queue.push(kind, key, job, job.weight, session)
            self._cond.notify()
        try:
            return await future
        except asyncio.CancelledError:
            job.abandoned = True
            raise

    def close(self) -> None:
        """Stop the workers once the jobs running now end; waiting jobs are dropped."""
        with self._cond:
            self._closed = True
            dropped = [self._queue.pop()[2] for _ in range(len(self._queue))]
            self._cond.notify_all()
        for job in dropped:
            self._resolve(job, None, Cancelled("the server is shutting down"))

    def _resolve(self, job: _Job, result, error: BaseException | None) -> None:
        try:
            job.loop.call_soon_threadsafe(_settle, job.future, result, error)
        except RuntimeError:  # the loop is closed: nobody waits any more
            pass

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job = self._take()
            if job is None:
                continue
            lent = [0.0]  # seconds of this job's worker time that its turns gave others
            long = job.weight > TURN_WEIGHT  # a short job gives no turns (it may be run in one itself)
            with taking_turns(partial(self._turn, time.perf_counter(), lent) if long else None):
                self._execute(job, lent)

    def _take(self) -> _Job | None:
        """The next job, counted as running; ``None`` when it was given up (it is settled so)."""
        job = self._queue.pop()[2]
        if job.abandoned or (job.cancelled is not None and job.cancelled.is_set()):
            self._queue.done(job.kind, job.key, -job.weight, job.session)
            self._resolve(job, None, Cancelled("the client went away"))
            return None
        self.running += 1
        return job

    def _execute(self, job: _Job, lent: list[float]) -> None:
        """Run a job :meth:`_take` took, charge what it took (less the ``lent[0]`` seconds its turns
        gave the jobs they ran, which are charged their own) and hand its result to its caller."""
        started = time.perf_counter()
        result = error = None
        try:
            result = job.fn(*job.args)
        except Exception as exc:  # noqa: BLE001 (handed to the waiting coroutine)
            error = exc
        spent = time.perf_counter() - started - lent[0]
        with self._cond:
            self.running -= 1
            self._queue.done(job.kind, job.key, spent - job.weight, job.session)
        self._resolve(job, result, error)

    def _turn(self, started: float, lent: list[float]) -> None:
        """A turn of the job running on this thread since ``started`` (:func:`vispeech.turns.give_turn`):
        the jobs waiting run here, in the queue's order, while every worker is busy (an idle one
        takes them itself), the next is estimated at most :data:`TURN_WEIGHT` and the time lent
        (``lent[0]``) stays below the job's own, so a long job holds a worker for no more than one
        of its pieces at a time and still has half of it. Only a job estimated above
        :data:`TURN_WEIGHT` takes turns (:meth:`_work`)."""
        while True:
            with self._cond:
                own = time.perf_counter() - started - lent[0]
                if (
                    self._closed
                    or not self._queue
                    or self.running - self._lent < self.workers  # a thread is idle: it takes them
                    or lent[0] >= own
                    or self._queue.next_weight() > TURN_WEIGHT
                ):
                    return
                job = self._take()
                self._lent += job is not None
            if job is not None:
                begun = time.perf_counter()
                try:
                    with taking_turns(None):  # a job run in a turn gives none of its own
                        self._execute(job, [0.0])
                finally:
                    with self._cond:
                        self._lent -= 1
                lent[0] += time.perf_counter() - begun
