"""A batch on Ray: the same lines and outputs as the local pool, spread over a cluster.

Each line goes to one of ``workers`` stateful actors (:class:`_Animator`, one CPU each), the one
with the fewest lines in hand; an actor loads its models once and prepares and animates every
line it is given (:func:`~vispeech.batch.line.prepare`: speech synthesis, reading and aligning a
recording, reading an alignment; :func:`~vispeech.batch.line.animate_prepared`), as a worker of
the local pool does, so a core does the same work on either backend. The driver (this process)
writes each result with :func:`~vispeech.batch.line.write_line`, so the files land in the
driver's output folder in the same layout, byte for byte what the local pool writes, whichever
nodes computed them. Input files must be readable at the same paths on every node (a shared
file system).

``address`` joins a running cluster (``ray start --head`` on one machine, ``ray start
--address HEAD:6379`` on the others; or ``"auto"``), whose CPUs cap the number of actors;
without it a local Ray instance of ``workers`` CPUs is started for the run and stopped after
it, its workers at the priority of the local pool's (Ray's own default, nice 15, gives way to
any other work on the machine). Needs the ``ray`` extra.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from vispeech.batch.job import BatchLine
from vispeech.batch.line import LineResult, animate_prepared, failed, prepare, write_line

IN_FLIGHT_PER_WORKER = 4
"""Lines each actor may have in hand: bounds the results held in the object store."""


def execute_on_ray(
    todo: list[tuple[BatchLine, str, str]], out: Path, workers: int, address: str | None
) -> Iterator[LineResult]:
    """Run ``todo`` (line, key, record) on Ray, yielding each line's result as it is written."""
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            ray.init(
                num_cpus=workers,
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.ERROR,
                _system_config={"worker_niceness": 0},  # Ray's default, 15, yields to any other work
            )
        else:
            ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    try:
        workers = max(1, min(workers, int(ray.cluster_resources().get("CPU", workers))))  # each actor holds a CPU
        animator = ray.remote(num_cpus=1, max_restarts=1)(_Animator)
        # Any: ray types an actor method's .remote only under @ray.method, and ray is an optional
        # extra, imported here only
        actors: list[Any] = [animator.remote() for _ in range(workers)]
        in_hand = [0] * workers
        queue = list(reversed(todo))
        pending: dict = {}  # object ref → (line, key, record, actor, start time)
        while queue or pending:
            while queue and min(in_hand) < IN_FLIGHT_PER_WORKER:
                line, key, record = queue.pop()
                actor = in_hand.index(min(in_hand))
                in_hand[actor] += 1
                pending[actors[actor].animate.remote(line)] = (line, key, record, actor, time.perf_counter())
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                line, key, record, actor, started = pending.pop(ref)
                in_hand[actor] -= 1
                try:
                    files = write_line(line, out, ray.get(ref), key, record)
                except ray.exceptions.RayTaskError as exc:  # the line's own error, raised on a worker
                    yield failed(line, key, _cause(exc), time.perf_counter() - started)
                    continue
                except Exception as exc:  # noqa: BLE001 (a lost worker or a failed write: this line only)
                    yield failed(line, key, exc, time.perf_counter() - started)
                    continue
                yield LineResult(line.number, line.id, "written", key, files, seconds=time.perf_counter() - started)
    finally:
        if started_here:
            ray.shutdown()


def _cause(error: BaseException) -> BaseException:
    """The exception a line raised on a worker, out of Ray's wrappers."""
    import ray

    while isinstance(error, ray.exceptions.RayTaskError) and error.cause is not None:
        error = error.cause
    return error


class _Animator:
    """A Ray actor: prepares and animates lines with models it loads once."""

    def animate(self, line: BatchLine):
        return animate_prepared(line, prepare(line))
