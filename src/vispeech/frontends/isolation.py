"""Native libraries' work in supervised worker processes, where a crash or a hang cannot hurt.

espeak-ng, pocketsphinx and libsndfile are C code run on input someone else chose, and C code
can crash (espeak-ng segfaults on ``"1 2 3 4 5 6 7 8 9 10 100"`` in Greenlandic) or hang; in
the process of a server or a batch that would end every request or line at once.
:func:`run_isolated` runs such work in one of a pool of worker processes instead: pebble's
``ProcessPool``, whose workers are forked from this process (in milliseconds, sharing its
memory; in a process with threads the modules a worker needs are imported first, so that one
forked while another thread imports never waits on that import's lock; a worker closes the
sockets and the pipes it inherits, so that a server's connections end when the server closes
them and a program the caller feeds through a pipe sees the end of its input). A
worker that dies is replaced; a job that runs past its time limit has its worker killed and
replaced; either is a :class:`~vispeech.errors.NativeFailure` for that job alone, and the
other jobs go on (the standard library's ``ProcessPoolExecutor``, and loky's, fail every job
in flight when one worker dies, and have no time limit per job). A job pays about 0.15 ms
plus the copying of its arguments and result, a program about 0.1 s for starting and
stopping the pool (``benchmarks/bench_isolation.py``). :func:`run_isolated_many` sends several
jobs at once, one worker each; a job may isolate calls of its own (they run in place, in its
worker).

Chaos tests make a worker crash or hang on purpose through :data:`FAULT_VARIABLE`.
"""

from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import importlib
import logging
import multiprocessing
import multiprocessing.connection
import multiprocessing.context
import multiprocessing.util
import os
import signal
import stat
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import CancelledError
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from vispeech.errors import NativeFailure

TIME_LIMIT = 60.0
"""The most seconds one job may run in its worker; then the worker is killed and the job fails."""

FAULT_VARIABLE = "VISPEECH_FAULT"
"""For chaos tests: ``crash:MARKER`` (a segmentation fault) or ``hang:MARKER`` (sleeps past any
time limit) in the worker of every job with a text or bytes argument holding ``MARKER``; read
when a job is sent, so setting it takes effect at once."""

PRELOAD = ("soundfile", "pocketsphinx")
"""Modules imported before the pool starts when other threads run (those the workers import:
libsndfile's and pocketsphinx's bindings), so that no worker imports anything."""

Result = TypeVar("Result")

log = logging.getLogger("vispeech")

_lock = threading.Lock()
_pool: Any = None  # the pebble ProcessPool, made on first use
_pool_size = 0
_workers = 1
_worker_fault: tuple[str | None] | None = None  # in a worker: the fault of the job it runs (FAULT_VARIABLE)


def set_workers(workers: int) -> None:
    """Run at most ``workers`` jobs at once (default 1; a server sets its own number); a pool of
    another size is replaced after its jobs end."""
    global _workers
    if workers < 1:
        raise ValueError("workers must be at least 1")
    with _lock:
        _workers = workers
        if _pool is not None and _pool_size != workers:
            _replace_pool()


def workers() -> int:
    """How many jobs run at once (:func:`set_workers`)."""
    return _workers


def _replace_pool() -> None:
    """Under ``_lock``: forget the pool, its jobs ending, then its workers (a new one is made on next use)."""
    global _pool
    _pool.close()
    threading.Thread(target=_pool.join, name="vispeech-native-pool-join", daemon=True).start()
    _pool = None


def run_isolated(library: str, what: str, fn: Callable[..., Result], *args: Any, extra_time: float = 0.0) -> Result:
    """``fn(*args)`` in a worker process (``fn`` a module-level function without side effects,
    the arguments and result picklable); its exceptions are raised here. Called in a worker (a
    job whose work is isolated as a whole), ``fn(*args)`` runs there and then.

    A worker that crashes on the job, or runs it longer than :data:`TIME_LIMIT` (plus
    ``extra_time`` seconds, for a job that grows with its input), raises
    :class:`~vispeech.errors.NativeFailure`: ``"<library> crashed on <what>"`` or
    ``"<library> took more than 60 s on <what>"`` (``what``: ``"this text in language kl"``).
    When pebble loses track of a crash (a worker dying before its job's start was seen breaks
    the whole pool, failing every job in it), the pool is started anew and the job run once more.
    """
    result = run_isolated_many(library, what, fn, [args], TIME_LIMIT + extra_time)[0]
    if isinstance(result, NativeFailure):
        raise result
    return result


def run_isolated_many(
    library: str, what: str, fn: Callable[..., Result], calls: Sequence[tuple], limit: float | None = None
) -> list[Result | NativeFailure]:
    """``fn(*args)`` for each ``args`` of ``calls``, all sent to the workers at once (as many run
    together as there are workers, :func:`set_workers`): each call's result, or the
    :class:`~vispeech.errors.NativeFailure` of :func:`run_isolated` for a call whose worker
    crashed or ran past ``limit`` seconds (default :data:`TIME_LIMIT`); a call's own exception is
    raised. In a worker the calls run there, one after another."""
    from pebble import ProcessExpired

    if _worker_fault is not None:
        return [_call(_worker_fault[0], fn, args) for args in calls]
    limit = TIME_LIMIT if limit is None else limit
    pool = _running_pool()
    fault = os.environ.get(FAULT_VARIABLE)
    futures = [pool.schedule(_call, args=(fault, fn, args), timeout=limit) for args in calls]
    results: list[Result | NativeFailure] = []
    for args, future in zip(calls, futures):
        try:
            results.append(future.result())
        except ProcessExpired as exc:
            failure = NativeFailure(f"{library} crashed on {what}")
            log.warning("%s (worker exit code %s); the worker is replaced", failure, exc.exitcode)
            results.append(failure)
        except FutureTimeout:
            failure = NativeFailure(f"{library} took more than {limit:g} s on {what}")
            log.warning("%s; the worker is killed and replaced", failure)
            results.append(failure)
        except (CancelledError, RuntimeError) as exc:
            if isinstance(exc, RuntimeError) and not isinstance(exc, BrokenProcessPool) and pool.active:
                raise  # the job's own error
            results.append(_run_again(pool, library, what, fn, args, limit))
    return results


def _run_again(
    pool, library: str, what: str, fn: Callable[..., Result], args: tuple, limit: float
) -> Result | NativeFailure:
    """A call lost with the broken ``pool``: run once more in a pool started anew (a
    :class:`~vispeech.errors.NativeFailure` if that one breaks too)."""
    from pebble import ProcessExpired

    _discard(pool)
    log.warning("the pool of native workers broke; it is started anew")
    pool = _running_pool()
    try:
        return pool.schedule(_call, args=(os.environ.get(FAULT_VARIABLE), fn, args), timeout=limit).result()
    except FutureTimeout:
        failure = NativeFailure(f"{library} took more than {limit:g} s on {what}")
    except (ProcessExpired, CancelledError, BrokenProcessPool):
        failure = NativeFailure(f"{library} crashed on {what}")
        _discard(pool)
    except RuntimeError:
        if pool.active:
            raise  # the job's own error
        failure = NativeFailure(f"{library} crashed on {what}")
        _discard(pool)
    log.warning("%s, breaking the pool of native workers twice", failure)
    return failure


def _running_pool():
    """The pool, made (or made anew, when it broke), :data:`PRELOAD` imported first in a threaded process."""
    global _pool, _pool_size
    from pebble import ProcessPool

    with _lock:
        if _pool is None or not _pool.active:
            if threading.active_count() > 1:  # another thread could be importing one when a worker is forked
                for module in PRELOAD:
                    importlib.import_module(module)
            _pool = ProcessPool(max_workers=_workers, context=_WorkerContext())
            _pool_size = _workers
            # at exit (of the program, or of a multiprocessing child), before its children are waited for
            multiprocessing.util.Finalize(_pool, _stop, (_pool,), exitpriority=10)
        return _pool


def _discard(pool) -> None:
    global _pool
    with _lock:
        if _pool is pool:
            _pool = None
    _stop(pool)


def _stop(pool) -> None:
    """Stop ``pool``'s workers (their jobs lost)."""
    pool.stop()
    pool.join(timeout=5)


def _forget() -> None:
    """In a forked child: the parent's pool and its threads are not there."""
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget)


class _WorkerProcess(multiprocessing.context.ForkProcess):
    """A pool's worker, forked from the caller. It reports no crash of its own on stderr (the caller
    logs the crash) and holds none of the caller's sockets (a server's connections end when the
    server closes them) nor of the pipes the caller had when it was forked, but for the pool's
    channels it is handed (a program the caller feeds through a pipe sees the end of its input)."""

    def __init__(
        self,
        group: None = None,
        target: Callable[..., object] | None = None,
        name: str | None = None,
        args: tuple = (),
        kwargs: dict | None = None,
        *,
        daemon: bool | None = None,
    ) -> None:
        super().__init__(group, target, name, args, kwargs or {}, daemon=daemon)
        self._own_pipes = {connection.fileno() for connection in _connections(args)}
        self._callers_pipes: dict[int, int] = {}

    def start(self) -> None:
        """In the caller: note its pipes, before forking makes the new process's own."""
        pipes = _open_files(stat.S_ISFIFO)
        self._callers_pipes = {fd: inode for fd, inode in pipes.items() if fd not in self._own_pipes}
        super().start()

    def run(self) -> None:
        faulthandler.disable()
        signal.set_wakeup_fd(-1)  # the caller's (an event loop's socket, closed below): signals wake nobody here
        pipes = _open_files(stat.S_ISFIFO)  # a number the caller closed meanwhile may hold another pipe now
        closing = [fd for fd, inode in self._callers_pipes.items() if pipes.get(fd) == inode]
        for fd in closing + list(_open_files(stat.S_ISSOCK)):
            if fd > 2:
                with contextlib.suppress(OSError):
                    os.close(fd)
        super().run()


class _WorkerContext(multiprocessing.context.ForkContext):
    Process = _WorkerProcess


def _connections(args: tuple) -> list[multiprocessing.connection.Connection]:
    """The connections in ``args`` and in their attributes (a pebble channel's)."""
    found = []
    for arg in args:
        for value in (arg, *getattr(arg, "__dict__", {}).values()):
            for item in value if isinstance(value, (tuple, list)) else (value,):
                if isinstance(item, multiprocessing.connection.Connection):
                    found.append(item)
    return found


def _open_files(kind: Callable[[int], bool]) -> dict[int, int]:
    """This process's open file descriptors of ``kind`` (a :mod:`stat` test of a mode), with the
    inode each points at."""
    folder = "/proc/self/fd" if os.path.isdir("/proc/self/fd") else "/dev/fd"
    found = {}
    for name in os.listdir(folder):
        try:
            status = os.fstat(int(name))
        except OSError:  # the listing's own, closed since
            continue
        if kind(status.st_mode):
            found[int(name)] = status.st_ino
    return found


def _call(fault: str | None, fn: Callable[..., Result], args: tuple) -> Result:
    """In the worker: ``fn(*args)``, after the fault :data:`FAULT_VARIABLE` asks for, if any (for
    every call ``fn`` isolates in its turn too)."""
    global _worker_fault
    _worker_fault = (fault,)
    kind, _, marker = (fault or "").partition(":")
    if marker and any(
        (isinstance(a, str) and marker in a) or (isinstance(a, bytes) and marker.encode() in a) for a in args
    ):
        if kind == "crash":
            ctypes.string_at(0)  # reads address 0: SIGSEGV, as a crashing library would
        elif kind == "hang":
            time.sleep(1e6)
    return fn(*args)
