"""A batch on Ray: the same lines and outputs as the local pool, spread over a cluster.

Each line is a Ray task that prepares its inputs (:func:`~vispeech.batch.line.prepare`: speech
synthesis, reading and aligning a recording, reading an alignment: the I/O and features) and
hands them, through the object store, to one of ``workers`` stateful actors
(:class:`_Animator`), each of which loads a model once and animates every line it is given
(:func:`~vispeech.batch.line.animate_prepared`). The driver (this process) writes each result
with :func:`~vispeech.batch.line.write_line`, so the files land in the driver's output folder in
the same layout, byte for byte what the local pool writes, whichever nodes computed them. Input
files must be readable at the same paths on every node (a shared file system).

``address`` joins a running cluster (``ray start --head`` on one machine, ``ray start
--address HEAD:6379`` on the others; or ``"auto"``); without it a local Ray instance of
``workers`` CPUs is started for the run and stopped after it. Needs the ``ray`` extra.
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
"""Lines each actor may have queued: bounds the prepared audio held in the object store."""


def execute_on_ray(
    todo: list[tuple[BatchLine, str, str]], out: Path, workers: int, address: str | None
) -> Iterator[LineResult]:
    """Run ``todo`` (line, key, record) on Ray, yielding each line's result as it is written."""
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        else:
            ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
    try:
        prepare_task = ray.remote(num_cpus=1, max_retries=0)(prepare)
        animator = ray.remote(num_cpus=0, max_restarts=1)(_Animator)
        # Any: ray types an actor method's .remote only under @ray.method, and ray is an optional
        # extra, imported here only
        actors: list[Any] = [animator.remote() for _ in range(workers)]
        queue = list(reversed(todo))
        pending: dict = {}  # object ref → (line, key, record, start time)
        limit = IN_FLIGHT_PER_WORKER * workers
        while queue or pending:
            while queue and len(pending) < limit:
                line, key, record = queue.pop()
                actor = actors[line.number % len(actors)]
                ref = actor.animate.remote(line, prepare_task.remote(line))
                pending[ref] = (line, key, record, time.perf_counter())
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                line, key, record, started = pending.pop(ref)
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
    """The exception a line raised on a worker, out of Ray's wrappers (a task's error reaches
    the actor that was to use its result wrapped twice)."""
    import ray

    while isinstance(error, ray.exceptions.RayTaskError) and error.cause is not None:
        error = error.cause
    return error


class _Animator:
    """A Ray actor: animates prepared lines with models it loads once."""

    def animate(self, line: BatchLine, prepared):
        return animate_prepared(line, prepared)
