"""The bounded pool of worker threads that runs the server's CPU-heavy work, fair between clients."""

from __future__ import annotations

import asyncio
import heapq
import itertools
import threading
import time
from collections.abc import Callable


class Busy(Exception):
    """The work queue is full (HTTP 503 with ``Retry-After``, or a stream error)."""

    retry_after = 1


class Cancelled(Exception):
    """The job's client went away before it started: it never ran (HTTP 503 with ``Retry-After``)."""

    retry_after = 1


class _Job:
    __slots__ = ("abandoned", "args", "cancelled", "fn", "future", "key", "loop")

    def __init__(self, fn, args, key, future, loop, cancelled) -> None:
        self.fn, self.args, self.key = fn, args, key
        self.future, self.loop, self.cancelled = future, loop, cancelled
        self.abandoned = False


def _settle(future: asyncio.Future, result, error: BaseException | None) -> None:
    if future.done():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


class WorkPool:
    """A bounded pool of worker threads for the CPU-heavy work, with a bounded, fair queue.

    ``await pool.run(key, fn, *args)`` runs ``fn(*args)`` on one of ``workers`` threads and
    returns its result; with ``max_queue`` jobs already waiting it raises :class:`Busy` at
    once instead of queueing. Waiting jobs are taken in order of how much worker time their
    client (``key``, the IP address) has used lately (decaying with a ``half_life`` in
    seconds) plus the job's own estimated ``weight`` (seconds), a client's own jobs in order:
    a new or light client, or a short job, is served before a heavy client's next piece. A
    job whose ``cancelled`` event is set, or whose caller stopped waiting, is dropped unrun.
    """

    def __init__(self, workers: int, max_queue: int, half_life: float = 10.0) -> None:
        if workers < 1 or max_queue < 1:
            raise ValueError("workers and max_queue must be at least 1")
        self.workers = workers
        self.max_queue = max_queue
        self.half_life = half_life
        self._heap: list = []
        self._seq = itertools.count()
        self._cond = threading.Condition()
        self._usage: dict[str, tuple[float, float]] = {}  # key -> (seconds, time)
        self._waiting: dict[str, tuple[int, float]] = {}  # key -> (jobs queued, highest priority)
        self._threads: list[threading.Thread] = []
        self._closed = False
        self.running = 0

    @property
    def queued(self) -> int:
        return len(self._heap)

    def _usage_of(self, key: str, now: float) -> float:
        used, then = self._usage.get(key, (0.0, now))
        return used * 0.5 ** ((now - then) / self.half_life)

    def _start(self) -> None:
        while len(self._threads) < self.workers:
            thread = threading.Thread(target=self._work, name=f"vispeech-work-{len(self._threads)}", daemon=True)
            thread.start()
            self._threads.append(thread)

    async def run(self, key: str, fn: Callable, *args, cancelled: threading.Event | None = None, weight: float = 0.0):
        """``fn(*args)`` on a worker thread; :class:`Busy` when the queue is full, :class:`Cancelled`
        when ``cancelled`` was set before it started."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        job = _Job(fn, args, key, future, loop, cancelled)
        with self._cond:
            if self._closed:
                raise Busy("the server is shutting down")
            if len(self._heap) >= self.max_queue:
                raise Busy(f"server busy: {self.max_queue} jobs waiting, try again later")
            self._start()
            priority = self._usage_of(key, time.monotonic()) + max(0.0, weight)
            waiting, last = self._waiting.get(key, (0, priority))
            priority = max(priority, last)  # a client's own jobs stay in order
            self._waiting[key] = (waiting + 1, priority)
            heapq.heappush(self._heap, (priority, next(self._seq), job))
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
            dropped, self._heap = self._heap, []
            self._waiting.clear()
            self._cond.notify_all()
        for _, _, job in dropped:
            self._resolve(job, None, Cancelled("the server is shutting down"))

    def _resolve(self, job: _Job, result, error: BaseException | None) -> None:
        try:
            job.loop.call_soon_threadsafe(_settle, job.future, result, error)
        except RuntimeError:  # the loop is closed: nobody waits any more
            pass

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._heap and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                _, _, job = heapq.heappop(self._heap)
                waiting, last = self._waiting.pop(job.key, (1, 0.0))
                if waiting > 1:
                    self._waiting[job.key] = (waiting - 1, last)
                if job.abandoned or (job.cancelled is not None and job.cancelled.is_set()):
                    skip = True
                else:
                    skip = False
                    self.running += 1
            if skip:
                self._resolve(job, None, Cancelled("the client went away"))
                continue
            started = time.perf_counter()
            result = error = None
            try:
                result = job.fn(*job.args)
            except Exception as exc:  # noqa: BLE001 (handed to the waiting coroutine)
                error = exc
            spent = time.perf_counter() - started
            with self._cond:
                self.running -= 1
                now = time.monotonic()
                self._usage[job.key] = (self._usage_of(job.key, now) + spent, now)
                if len(self._usage) > 10_000:
                    self._usage = {k: v for k, v in self._usage.items() if self._usage_of(k, now) > 1e-3}
            self._resolve(job, result, error)
