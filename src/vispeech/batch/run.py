"""Running a batch: every line's outputs in a folder of its own, in parallel, resumable.

Each line is written as ``OUT/<id>/`` (the files ``say``, ``animate`` or ``animate-phones``
write, in the line's formats) plus ``batch.json``, its record: the key and what went in. The
folder is swapped in whole (:func:`vispeech.files.atomic_output_dir`), so a batch killed at
any moment leaves each line's folder complete, old or new, never half-written.

The key is a digest of everything the output depends on: vispeech's version, the input (the
text, or the bytes of the audio or alignment file), the language, the model's version
(:func:`vispeech.models.registry.model_version`: its parameters and weight files), frame
rate, speaking rate, formats and post-processing. A line whose folder holds a record with its
key and every file it names is left alone; so a rerun redoes exactly the lines that changed or
never finished. ``OUT/index.jsonl`` lists every line of the last run (written at its end).

Lines run on a pool of processes (pebble's), one per core by default; each process loads a
model once (forked, the workers share the models and pocketsphinx's decoders the parent
loaded) and runs NumPy's BLAS on one thread (threadpoolctl), as Ray runs its actors. A line
that fails is reported with its message and never stops the others, not even when its worker
process dies: a new worker takes the next line. Native code (espeak-ng,
pocketsphinx, libsndfile) runs in worker processes of its own
(:mod:`vispeech.frontends.isolation`) in any case, so a line it crashes on fails with that one
line with ``--jobs 1`` too.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path

from pebble import ProcessExpired, ProcessPool
from threadpoolctl import threadpool_limits

import vispeech
from vispeech.batch.job import BatchLine, JobDefaults, read_job
from vispeech.batch.line import RECORD, LineResult, expected_files, failed, loaded_model, model_spec, run_line
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.models.registry import model_version, saved_folder
from vispeech.motion.rigging.calibration import SCALES, load_scale

INDEX = "index.jsonl"
"""The file in the output folder that lists every line of the last run."""
BACKENDS = ("local", "ray")
"""Where lines run: a local pool of processes, or a Ray cluster."""


@dataclass
class BatchReport:
    """The results of a run, in line order, its wall time (s) and the index it wrote."""

    results: list[LineResult] = field(default_factory=list)
    seconds: float = 0.0
    index: Path | None = None

    def count(self, status: str) -> int:
        """How many lines ended with ``status``."""
        return sum(r.status == status for r in self.results)

    @property
    def failed(self) -> list[LineResult]:
        """The lines that failed."""
        return [r for r in self.results if r.status == "failed"]


def run_batch(
    job: str | os.PathLike | Sequence[BatchLine],
    out_dir: str | os.PathLike,
    *,
    defaults: JobDefaults = JobDefaults(),
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    force: bool = False,
    progress: Callable[[LineResult], None] | None = None,
) -> BatchReport:
    """Animate every line of ``job`` (a path for :func:`~vispeech.batch.job.read_job`, or its
    lines) into ``out_dir/<id>/`` and write ``out_dir/index.jsonl``.

    ``workers`` processes run the lines (default: one per core; 1 runs them in this process);
    ``backend="ray"`` runs them on a Ray cluster instead (``address``; default a local instance
    of ``workers`` CPUs; :mod:`vispeech.batch.cluster`), with the same outputs. ``force``
    redoes lines whose outputs are up to date; ``progress`` is called with each line's result
    as it ends. Raises :class:`VispeechError` only when the job cannot be read or ``out_dir``
    cannot be made; every problem of a line is in its result.
    """
    started = time.perf_counter()
    if backend not in BACKENDS:
        raise VispeechError(f"unknown batch backend {backend!r} (use {' or '.join(BACKENDS)})")
    lines = read_job(job, defaults) if isinstance(job, str | os.PathLike) else list(job)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise VispeechError(f"output path {out} exists and is not a folder")
    if Path(os.path.realpath(out)).parent == Path(os.path.realpath(out)):
        raise VispeechError(f"output folder {out} is the root folder: give a folder for the batch's folders")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise VispeechError(f"cannot make output folder {out}: {exc.strerror or exc}") from None

    results: dict[int, LineResult] = {}
    todo: list[tuple[BatchLine, str, str]] = []  # line, key, record
    versions = _load_models({model_spec(line) for line in lines if line.error is None})
    for line in lines:
        result, key, record = _plan(line, out, versions, force)
        if result is None:
            todo.append((line, key, record))
        else:
            results[line.number] = result
            if progress is not None:
                progress(result)
    for result in _execute(todo, out, workers, backend, address):
        results[result.number] = result
        if progress is not None:
            progress(result)

    index = out / INDEX
    report = BatchReport([results[line.number] for line in lines], time.perf_counter() - started, index)
    with atomic_output_file(index) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            for result in report.results:
                f.write(json.dumps(asdict(result), ensure_ascii=False) + "\n")
    return report


def _load_models(specs: set[str]) -> dict[str, str | VispeechError]:
    """Load each model once (kept for this process and forked workers): spec → its version, or the error loading it."""
    versions: dict[str, str | VispeechError] = {}
    for spec in sorted(specs):
        try:
            model = loaded_model(spec)
            model.check_fitted()
            versions[spec] = model_version(model, saved_folder(spec))
        except VispeechError as exc:
            versions[spec] = exc
    return versions


def _plan(line: BatchLine, out: Path, versions: dict, force: bool) -> tuple[LineResult | None, str, str]:
    """``(result, key, record)``: a result when the line needs no run (it failed already, or is up to date)."""
    if line.error is not None:
        return failed(line, None, line.error), "", ""
    version = versions[model_spec(line)]
    if isinstance(version, VispeechError):
        return failed(line, None, version), "", ""
    try:
        digest = None if line.source is None else _file_digest(line.source, line.kind)
    except VispeechError as exc:
        return failed(line, None, exc), "", ""
    inputs = {
        "kind": line.kind,
        "text": line.text,
        "language": line.language,
        "source": None if line.source is None else str(line.source),
        "source_sha256": digest,
    }
    settings = {
        "model": model_spec(line),
        "model_version": version,
        "fps": line.fps,
        "rate": line.rate,
        "formats": list(line.formats),
        "postprocessing": line.postprocessing,
        "scale": _scale_settings(line.scale),
        "voice": line.voice,
        "life": list(line.life),
        "seed": line.seed if line.life else None,
    }
    about = {"vispeech": vispeech.__version__, **inputs, **settings, "source": None}
    key = hashlib.sha256(json.dumps(about, sort_keys=True).encode()).hexdigest()[:32]
    record = (
        json.dumps(
            {
                "format": "vispeech-batch-line",
                "version": 1,
                "id": line.id,
                "key": key,
                "vispeech": vispeech.__version__,
                **inputs,
                **settings,
            },
            indent=1,
        )
        + "\n"
    )
    if not force and _up_to_date(out / line.id, key, expected_files(line)):
        return LineResult(line.number, line.id, "unchanged", key, expected_files(line)), key, record
    return None, key, record


def _file_digest(path: Path, kind: str) -> str:
    if not path.is_file():
        raise VispeechError(f"{kind} file {path} not found" if not path.exists() else f"{kind} {path} is not a file")
    try:
        with open(path, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError as exc:
        raise VispeechError(f"cannot read {kind} {path}: {exc.strerror or exc}") from None


def _up_to_date(folder: Path, key: str, names: tuple[str, ...]) -> bool:
    """True when ``folder``'s record has ``key`` and every file in ``names`` is there."""
    try:
        record = json.loads((folder / RECORD).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(record, dict) and record.get("key") == key and all((folder / n).is_file() for n in names)


def _execute(todo: list[tuple[BatchLine, str, str]], out: Path, workers: int | None, backend: str, address: str | None):
    """Run the lines, yielding each result as it ends: on Ray (:mod:`vispeech.batch.cluster`), in a
    pool of processes, or in this process when ``workers`` is 1 or there is one line."""
    workers = max(1, workers or os.cpu_count() or 1)
    if not todo:
        return
    if backend == "ray":
        from vispeech.batch.cluster import execute_on_ray

        yield from execute_on_ray(todo, out, workers, address)
        return
    from vispeech.frontends.align import default_method, load_decoders

    if any(
        line.kind == "audio" and line.text is not None and default_method(line.language or "en") == "pocketsphinx"
        for line, _, _ in todo
    ):
        load_decoders()  # once, before the workers and their native workers are forked
    # the lines run side by side, one a core: OpenBLAS's threads would only spin, waiting for
    # work, on the cores the other lines need (a quarter of a line's CPU time); Ray's actors get
    # one thread from Ray
    with threadpool_limits(1, user_api="blas"):
        yield from _run_locally(todo, out, min(workers, len(todo)))


def _run_locally(todo: list[tuple[BatchLine, str, str]], out: Path, workers: int) -> Iterator[LineResult]:
    """Run the lines in this process (one worker) or in a pool of ``workers`` forked processes."""
    if workers == 1:
        for line, key, record in todo:
            yield run_line(line, out, key, record)
        return
    pool = ProcessPool(max_workers=workers, context=multiprocessing.get_context("fork"))
    try:
        pending: dict[Future[LineResult], tuple[BatchLine, str]] = {
            pool.schedule(run_line, (line, out, key, record)): (line, key) for line, key, record in todo
        }
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                line, key = pending.pop(future)
                try:
                    yield future.result()
                except ProcessExpired as exc:  # killed, out of memory: that line failed, a new worker takes the next
                    yield failed(line, key, f"its worker process ended (exit code {exc.exitcode})")
                except Exception as exc:  # noqa: BLE001 (a result that could not come back)
                    yield failed(line, key, exc)
    finally:
        pool.stop()
        pool.join()


def _scale_settings(scale: str) -> str | dict[str, float]:
    """What of the output scale a line's key depends on: its name, or a calibration file's gains."""
    calibration = load_scale(scale)
    return scale if calibration is None or scale in SCALES else calibration.gains
