"""``vispeech batch`` with audio lines: 3-s grid_s1 clips with their transcripts, alignment included.

    python benchmarks/bench_batch_audio.py [--lines 60] [--jobs 1 2] [--no-ray] [--keep DIR] [--trust-transcripts]

Makes a manifest of ``--lines`` grid_s1 utterances (a seed-0 sample; audio + transcript, so each
line is read, aligned by pocketsphinx with its transcript fit checked, animated by the default
model for a recording with its transcript, :func:`vispeech.pipeline.recording_model`, and written
with the default outputs), then runs ``vispeech batch`` on it as a real process for the
local backend with each ``--jobs`` and, when Ray is installed (the ``ray`` extra), for the Ray
backend with the same numbers of workers. Each configuration runs twice: on ``--lines`` lines
and on ``2 × jobs`` of them, so that start-up (Python, the models, the pocketsphinx decoders, a
Ray instance) can be told from the steady rate:

- ``lines/s``: lines over the whole run, start-up included (what ``vispeech batch`` prints);
- ``steady lines/s``: the extra lines of the long run over its extra seconds;
- ``CPU s/line``: CPU seconds of the long run's process tree per line, with one local worker
  only (the native workers of a pool's workers, and Ray's, are not always waited for, so their
  time is not always counted).

``vispeech batch`` runs as a user runs it, without the thread-count variables of
:data:`THREAD_VARIABLES` (``OMP_NUM_THREADS=1`` would hide the threads NumPy's BLAS starts).
``--trust-transcripts`` runs ``vispeech batch --trust-transcripts``: the transcripts are aligned
without the check that they fit the audio (:func:`vispeech.frontends.align.transcript_fit`).
Every configuration's line folders must be byte-identical to the first one's; the load average
is printed with each figure (other work on the machine slows every one). Failed lines are
listed; exits non-zero if a line fails or an output differs.
"""

from __future__ import annotations

import argparse
import csv
import filecmp
import importlib.util
import json
import os
import random
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Left out of ``vispeech batch``'s environment: what it does with threads is measured too."""


def write_job(path: Path, n: int) -> list[str]:
    """A manifest of ``n`` grid_s1 utterances with their transcripts; their ids."""
    with open(GRID / "sentences.tsv", encoding="utf-8") as f:
        texts = {row["id"]: row["text"] for row in csv.DictReader(f, delimiter="\t")}
    ids = random.Random(0).sample(sorted(texts), n)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["id", "audio", "text"])
        for name in ids:
            writer.writerow([name, GRID / "utterances" / f"{name}.flac", texts[name]])
    return ids


def batch(job: Path, out: Path, jobs: int, backend: str, trust: bool = False) -> tuple[float, float, list[str]]:
    """Wall seconds, CPU seconds (this run's process tree) and failed lines of one ``vispeech batch`` run."""
    command = [sys.executable, "-c", "from vispeech.cli import main; main()", "batch", str(job), "-o", str(out)]
    command += ["-j", str(jobs), "-q", "--force", "--backend", backend] + ["--trust-transcripts"] * trust
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    env = {name: value for name, value in os.environ.items() if name not in THREAD_VARIABLES}
    result = subprocess.run(command, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode not in (0, 1) or not (out / "index.jsonl").is_file():  # 1: some lines failed
        sys.exit(f"vispeech batch failed ({result.returncode}): {(result.stdout + result.stderr).strip()[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    index = [json.loads(line) for line in (out / "index.jsonl").read_text(encoding="utf-8").splitlines()]
    return seconds, cpu, [f"{r['id']}: {r['error']}" for r in index if r["status"] != "written"]


def differing(ids: list[str], a: Path, b: Path) -> list[str]:
    """The line folders of ``a`` and ``b`` whose files are not byte for byte the same."""
    bad = []
    for name in ids:
        if not (a / name).is_dir() or not (b / name).is_dir():
            continue  # a failed line, reported as such
        files = sorted(p.name for p in (a / name).iterdir())
        match, mismatch, errors = filecmp.cmpfiles(a / name, b / name, files, shallow=False)
        if mismatch or errors or sorted(p.name for p in (b / name).iterdir()) != files:
            bad.append(name)
    return bad


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lines", type=int, default=60)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray backend even when Ray is installed")
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    parser.add_argument("--trust-transcripts", action="store_true", help="align without checking the transcripts' fit")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="vispeech-bench-batch-audio-"))
    work.mkdir(parents=True, exist_ok=True)
    backends = ["local"]
    if not args.no_ray:
        if importlib.util.find_spec("ray") is None:
            print("Ray is not installed (the ray extra): the Ray backend is not measured")
        else:
            backends.append("ray")
    ids = write_job(work / "job.csv", args.lines)
    trusted = ", transcripts trusted (no fit check)" if args.trust_transcripts else ""
    print(f"{args.lines} grid_s1 lines (audio + transcript){trusted}, {os.cpu_count()} cores; work in {work}")
    print(f"{'backend':8s} {'jobs':>4s} {'lines/s':>8s} {'steady lines/s':>15s} {'CPU s/line':>11s}  load (1, 5 min)")
    reference, ok = None, True
    try:
        for backend in backends:
            for jobs in args.jobs:
                short = work / "short.csv"
                with open(work / "job.csv", encoding="utf-8") as f:
                    short.write_text("".join(f.readlines()[: 2 * jobs + 1]), encoding="utf-8")
                shutil.rmtree(work / "short", ignore_errors=True)
                short_seconds, _, _ = batch(short, work / "short", jobs, backend, args.trust_transcripts)
                out = work / f"out-{backend}-{jobs}"
                seconds, cpu, failures = batch(work / "job.csv", out, jobs, backend, args.trust_transcripts)
                steady = (args.lines - 2 * jobs) / max(seconds - short_seconds, 1e-9)
                load = os.getloadavg()
                per_line = f"{cpu / args.lines:11.3f}" if (backend, jobs) == ("local", 1) else f"{'-':>11s}"
                print(
                    f"{backend:8s} {jobs:4d} {args.lines / seconds:8.2f} {steady:15.2f} {per_line}"
                    f"  {load[0]:.2f} {load[1]:.2f}"
                )
                for failure in failures:
                    print(f"  failed: {failure}")
                ok &= not failures
                if reference is None:
                    reference = out
                elif bad := differing(ids, reference, out):
                    print(f"  outputs differ from {reference.name} in {len(bad)} lines: {', '.join(bad[:5])}")
                    ok = False
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    if not ok:
        sys.exit(1)


if __name__ == "__main__":
    main()
