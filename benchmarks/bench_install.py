"""The core install: its size, and the first and second ``vispeech animate`` of a fresh install.

    python benchmarks/bench_install.py [--source REPO] [--grid GRID_DIR] [--runs N] [--keep DIR]

Makes a fresh virtual environment, ``pip install``s the working tree of ``--source`` (default:
this repository; tracked and untracked files that git does not ignore, copied to a temporary
folder with the built web app so that no stale ``build/`` folder leaks in; the web build is
skipped with ``VISPEECH_SKIP_WEB_BUILD=1`` where ``src/vispeech/serve/static/`` is built,
else setup.py builds it with npm), then reports:

- the venv's size on disk in MiB (as ``du -sm`` counts it; MB beside it), counting the pip
  and setuptools that ``python -m venv`` puts in every venv (their share and the size without
  them beside it), the largest installed distributions (the files their RECORDs list, in
  MiB), and which of the heavy packages the core must not pull are installed;
- whole-process wall times on one core: ``python -c pass``, ``vispeech say``, then the first
  ``vispeech animate`` of the install on 10 s of GRID speaker 1 audio (its first utterances
  one after another, cut to 10 s, written by the venv's own Python) and ``N`` more runs.

Targets (issue 25): the venv ≤ 300 MiB; the first animate ≤ 2 s, as fast as the second.
Every process is pinned to one CPU with OpenMP/OpenBLAS/MKL threads set to 1. A fresh
install takes a few minutes (pip from PyPI or local disk).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_GRID = ROOT.parent / "shared" / "data" / "grid_s1"
STATIC = Path("src") / "vispeech" / "serve" / "static"
HEAVY = ("numba", "llvmlite", "pandas", "scikit-learn", "scipy", "torch", "matplotlib")
"""Distributions the core install must not contain."""
VENV_TOOLS = ("pip", "setuptools")
"""Distributions ``python -m venv`` installs (Python 3.11), not vispeech's requirements."""
SIZE_TARGET_MIB = 300.0
FIRST_TARGET_S = 2.0
CLIP_SECONDS = 10.0
CPU = min(os.sched_getaffinity(0))

_WRITE_CLIP = """
import sys
from pathlib import Path
import numpy as np
import soundfile
folder, out, seconds = Path(sys.argv[1]), sys.argv[2], float(sys.argv[3])
parts, rate = [], 16000
for path in sorted(folder.glob("*.flac")):
    samples, rate = soundfile.read(path, dtype="float32")
    parts.append(samples)
    if sum(len(p) for p in parts) >= seconds * rate:
        break
soundfile.write(out, np.concatenate(parts)[: round(seconds * rate)], rate)
"""

_SIZES = """
import json
from importlib.metadata import distributions
sizes = {}
for dist in distributions():
    total = 0
    for file in dist.files or ():
        path = file.locate()
        if path.is_file():
            total += path.stat().st_size
    sizes[dist.metadata["Name"]] = total
print(json.dumps(sizes))
"""


def _pin() -> None:
    os.sched_setaffinity(0, {CPU})


def copy_tree(source: Path, target: Path) -> None:
    """The files of ``source``'s working tree that git does not ignore, and its built web app."""
    listed = subprocess.run(
        ["git", "-C", str(source), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        capture_output=True, text=True, check=True,
    ).stdout.split("\0")
    for name in filter(None, listed):
        path = source / name
        if path.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target / name)
    if (source / STATIC).is_dir():
        shutil.copytree(source / STATIC, target / STATIC, dirs_exist_ok=True)


def install(source: Path, venv: Path) -> float:
    """A fresh venv at ``venv`` with ``source`` installed (no extras); the seconds it took."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    with tempfile.TemporaryDirectory(prefix="bench_install_src_") as tree:
        copy_tree(source, Path(tree))
        env = dict(os.environ)
        if (Path(tree) / STATIC / "index.html").is_file():
            env["VISPEECH_SKIP_WEB_BUILD"] = "1"
        result = subprocess.run([str(venv / "bin" / "pip"), "install", "--no-cache-dir", "-q", tree],
                                env=env, capture_output=True, text=True)
        if result.returncode:
            raise SystemExit(f"pip install failed:\n{result.stdout}\n{result.stderr}")
    return time.perf_counter() - start


def disk_bytes(folder: Path) -> int:
    """Bytes that ``folder`` takes on disk, as ``du -s`` counts them."""
    return sum(p.lstat().st_blocks * 512 for p in folder.rglob("*"))


def timed(command: list[str], cwd: Path) -> float:
    """Wall seconds of one run of ``command`` on one core; stops on a failure."""
    start = time.perf_counter()
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, preexec_fn=_pin)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({result.returncode}):\n{result.stderr}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", type=Path, default=ROOT, help="The repository to install [default: this one].")
    parser.add_argument("--grid", type=Path, default=DEFAULT_GRID, help="GRID speaker 1 (its utterances/ folder).")
    parser.add_argument("--runs", type=int, default=3, help="Timed runs after the first animate (median reported).")
    parser.add_argument("--keep", type=Path, default=None, help="Make the venv here and keep it.")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_install_") as tmp:
        tmp = Path(tmp)
        venv = args.keep or tmp / "venv"
        if venv.exists():
            raise SystemExit(f"{venv} exists: give a new folder")
        seconds = install(args.source.resolve(), venv)
        python, vispeech = str(venv / "bin" / "python"), str(venv / "bin" / "vispeech")
        size = disk_bytes(venv) / 2**20
        sizes = json.loads(subprocess.run([python, "-c", _SIZES], capture_output=True, text=True, check=True).stdout)
        clip = tmp / "speech.wav"
        subprocess.run([python, "-c", _WRITE_CLIP, str(args.grid / "utterances"), str(clip), str(CLIP_SECONDS)],
                       check=True)
        passes = [timed([python, "-c", "pass"], tmp) for _ in range(args.runs)]
        say = timed([vispeech, "say", "Place blue at F two now.", "-o", str(tmp / "say")], tmp)
        animate = [vispeech, "animate", str(clip), "-o"]
        first = timed([*animate, str(tmp / "animate0")], tmp)
        later = [timed([*animate, str(tmp / f"animate{i + 1}")], tmp) for i in range(args.runs)]

    heavy = sorted(name for name in sizes if name.lower() in HEAVY)
    print(f"pip install {args.source} (no extras) into a fresh venv: {seconds:.0f} s")
    print(f"venv size: {size:.0f} MiB, {size * 2**20 / 1e6:.0f} MB "
          f"(target {SIZE_TARGET_MIB:.0f} MiB: {'ok' if size <= SIZE_TARGET_MIB else 'OVER'})")
    tools = sum(sizes.get(name, 0) for name in VENV_TOOLS) / 2**20
    print(f"  counted: {' and '.join(VENV_TOOLS)} of `python -m venv`, {tools:.0f} MiB; "
          f"without them {size - tools:.0f} MiB")
    print(f"heavy packages installed: {', '.join(heavy) or 'none'}")
    print("largest distributions (MiB of files):")
    for name, total in sorted(sizes.items(), key=lambda item: -item[1])[:12]:
        print(f"  {name:<28} {total / 2**20:7.1f}")
    print(f"one core (CPU {CPU}); seconds, whole process")
    print(f"  python -c pass (median of {args.runs})        {statistics.median(passes):7.3f}")
    print(f"  vispeech say (first run)                   {say:7.3f}")
    print(f"  vispeech animate {CLIP_SECONDS:g}-s clip, first run     {first:7.3f} "
          f"(target {FIRST_TARGET_S:g}: {'ok' if first <= FIRST_TARGET_S else 'OVER'})")
    print(f"  vispeech animate, later runs (median of {args.runs}) {statistics.median(later):7.3f}")


if __name__ == "__main__":
    main()
