"""Fuzz the command line with malformed input files of every format.

    python benchmarks/fuzz_files.py [--count 1000] [--workers 8] [--timeout 10] [--memory-mb 1024]
                                    [--seed 0] [--max-seconds 900] [--keep DIR] [--json REPORT.json]

Generates ``--count`` malformed files spread over every input format: alignments (TextGrid,
HTK lab, GRID align, JSON), animation JSON, Live Link CSV, TalkingHead JSON, pose tables and
base GLBs, plus a symlink to /dev/zero, a FIFO, a folder, deeply nested JSON, UTF-16 with an
odd byte count and binary garbage. Each file is given to the command that reads it
(``animate-phones``, ``convert``, ``convert --pose-table``, ``convert --glb``) in a subprocess
with a ``--timeout`` second wall-clock limit and a ``--memory-mb`` address-space cap
(``resource.setrlimit`` in ``preexec_fn``). Every run is classified:

- ``error-line``: exit 2 and exactly one stderr line, starting ``error:`` (what bad input must give)
- ``accepted``: exit 0 (the mutation left a valid file)
- ``traceback``: a Python traceback on stderr
- ``hang``: still running after the timeout (killed)
- ``over-memory``: peak RSS over the cap, a MemoryError, or killed by a signal
- ``other``: anything else (a wrong exit code, several lines)

Prints the counts per format and overall, and examples of every class but the first two.
The acceptance bar (issue 8): every malformed file ends as ``error-line`` or ``accepted``;
no traceback, hang or over-memory. Bounded by ``--count`` and ``--max-seconds``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from vispeech.alignment.formats import write_alignment
from vispeech.alignment.phones import Phone, PhoneSequence, Word
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.formats.animation_json import write_animation_json, write_talkinghead_json
from vispeech.motion.formats.livelink import write_livelink_csv
from vispeech.motion.track import Track

CLI = "import sys; from vispeech.cli import main; sys.argv[0] = 'vispeech'; main()"
HOSTILE = ["-1", "-0.5", "nan", "NaN", "Infinity", "-inf", "1e999", "9" * 400, "1e6", "1000000", "0", "",
           "1.5.2", "0x10", "-0", "1e-320", "18446744073709551616", "3" * 5000]
FORMATS = ["textgrid", "lab", "align", "phones-json", "animation-json", "livelink", "talkinghead", "pose-table",
           "glb", "special"]


def seeds(folder: Path) -> dict[str, Path]:
    """A valid file of every format (written by vispeech's writers)."""
    phones = PhoneSequence([Phone("sil", 0.0, 0.2), Phone("HH", 0.2, 0.3, 0), Phone("AH", 0.3, 0.45, 0, 1),
                            Phone("L", 0.45, 0.55, 0), Phone("OW", 0.55, 0.8, 0, 1), Phone("sil", 0.8, 1.0)],
                           "en", [Word("hello", 0.2, 0.8)])
    rng = np.random.default_rng(0)
    track = Track(np.round(rng.uniform(0, 1, (36, len(ARKIT_NAMES))), 6), ARKIT_NAMES, 30.0)
    out = {
        "textgrid": folder / "seed.TextGrid", "lab": folder / "seed.lab", "align": folder / "seed.align",
        "phones-json": folder / "seed.phones.json", "animation-json": folder / "seed.json",
        "livelink": folder / "seed.csv", "talkinghead": folder / "seed.talkinghead.json",
        "pose-table": folder / "seed.pose.json", "glb": folder / "seed.glb",
    }
    for kind in ("textgrid", "lab", "align", "phones-json"):
        write_alignment(phones, out[kind])
    write_animation_json(track, out["animation-json"], phones=phones)
    write_livelink_csv(track, out["livelink"])
    write_talkinghead_json(track, out["talkinghead"])
    out["pose-table"].write_text(json.dumps(
        {"type": "morph", "poses": {"viseme_aa": {"jawOpen": 0.6}, "viseme_PP": {"mouthClose": 0.8, "mouthPressLeft":
                                                                                 0.3}},
         "rest": "viseme_sil", "ridge": 0.02, "range": [0, 1]}))
    out["glb"].write_bytes(_glb())
    return out


def _glb() -> bytes:
    import pygltflib

    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")
    blob = positions.tobytes() * 3
    gltf = pygltflib.GLTF2(
        scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0)],
        meshes=[pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0),
                                                               targets=[{"POSITION": 1}, {"POSITION": 2}])],
                               extras={"targetNames": ["jawOpen", "mouthClose"]})],
        accessors=[pygltflib.Accessor(bufferView=i, componentType=pygltflib.FLOAT, count=3, type="VEC3",
                                      min=[0, 0, 0], max=[1, 1, 0]) for i in range(3)],
        bufferViews=[pygltflib.BufferView(buffer=0, byteOffset=36 * i, byteLength=36) for i in range(3)],
        buffers=[pygltflib.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(blob)
    return b"".join(gltf.save_to_bytes())


def mutate(data: bytes, rng: random.Random, kind: str) -> bytes:
    """One to three mutations, each a cut, byte flip, insertion, duplication, hostile number or structural edit."""
    for _ in range(rng.randint(1, 3)):
        choice = rng.choice(["cut", "flip", "insert", "duplicate", "number", "number", "number", "structure"])
        n = len(data)
        if n == 0:
            return data
        if choice == "cut":
            data = data[:rng.randrange(n)]
        elif choice == "flip":
            i = rng.randrange(n)
            data = data[:i] + bytes([data[i] ^ rng.randrange(1, 256)]) + data[i + 1:]
        elif choice == "insert":
            i = rng.randrange(n + 1)
            data = data[:i] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 32))) + data[i:]
        elif choice == "duplicate":
            i = rng.randrange(n)
            j = min(n, i + rng.randint(1, 400))
            data = data[:j] + data[i:j] * rng.randint(1, 5) + data[j:]
        elif choice == "number":
            import re

            numbers = list(re.finditer(rb"-?\d+(?:\.\d+)?(?:e-?\d+)?", data))
            if numbers:
                m = rng.choice(numbers)
                data = data[:m.start()] + rng.choice(HOSTILE).encode() + data[m.end():]
        else:
            try:
                data = _structural(data, rng, kind)
            except (ValueError, RecursionError):  # an earlier mutation left no structure to edit
                pass
    return data


def _structural(data: bytes, rng: random.Random, kind: str) -> bytes:
    """A format-aware edit: declared counts, swapped lines, negative or huge times, deep nesting, lying lengths."""
    if kind == "textgrid":
        text = data.decode("latin-1")
        edits = [("intervals: size = 6", f"intervals: size = {rng.choice([0, 1, 5, 7, 8, 10**6])}"),
                 ("size = 2", f"size = {rng.choice([0, 1, 3, 99])}"), ("xmin = 0.2", "xmin = -0.2"),
                 ("xmax = 0.45", "xmax = 0.25"), ("xmax = 1", "xmax = 1e6"), ('"IntervalTier"', '"TextTier"'),
                 ("<exists>", "<absent>"), ('"phones"', '"words"')]
        old, new = rng.choice(edits)
        return text.replace(old, new, 1).encode("latin-1")
    if kind in ("lab", "align", "livelink"):
        lines = data.split(b"\n")
        if len(lines) > 3:
            i, j = rng.randrange(1, len(lines) - 1), rng.randrange(1, len(lines) - 1)
            lines[i], lines[j] = lines[j], lines[i]
        return b"\n".join(lines)
    if kind == "glb":
        buf = bytearray(data)
        if len(buf) >= 24:
            field = rng.choice([8, 12, 20 + struct.unpack_from("<I", buf, 12)[0]])
            if field + 4 <= len(buf):
                struct.pack_into("<I", buf, field, rng.choice([0, 1, 2 ** 31, 2 ** 32 - 1, len(buf) * 2]))
        return bytes(buf)
    obj = json.loads(data)
    depth = rng.choice([50, 1000, 100_000])
    nest = "[" * depth + "]" * depth
    key = rng.choice(list(obj)) if isinstance(obj, dict) and obj else "x"
    text = json.dumps(obj)
    target = json.dumps(obj.get(key)) if isinstance(obj, dict) else None
    if target and target in text:
        return text.replace(target, rng.choice([nest, '"x"', "null", "{}", "[]", "-1", "1e308", "[[1,2],[3]]"]),
                            1).encode()
    return nest.encode()


def special_files(folder: Path, rng: random.Random, count: int) -> list[tuple[str, Path]]:
    """Symlinks to /dev/zero, FIFOs, folders, deep JSON, odd UTF-16, garbage, empty and huge files."""
    cases = []
    suffixes = [".TextGrid", ".lab", ".align", ".json", ".csv", ".talkinghead.json"]
    for i in range(count):
        suffix = rng.choice(suffixes)
        path = folder / f"special{i}{suffix}"
        what = i % 8
        if what == 0:
            path.symlink_to("/dev/zero")
        elif what == 1:
            os.mkfifo(path)
        elif what == 2:
            path.mkdir()
        elif what == 3:
            depth = rng.choice([1000, 100_000, 1_000_000])
            path.write_text("[" * depth + "]" * depth if rng.random() < 0.5 else '{"a":' * depth + "0" + "}" * depth)
        elif what == 4:
            path.write_bytes(b"\xff\xfe" + "0 1 sil\n".encode("utf-16-le") * rng.randint(1, 50) + b"\x00")
        elif what == 5:
            path.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randint(1, 4096))))
        elif what == 6:
            path.write_bytes(b"" if rng.random() < 0.5 else b" \n\t\n")
        else:
            with open(path, "wb") as f:  # sparse: 200 MB, over the 128 MiB limit
                f.truncate(200 * 1024 * 1024)
        cases.append(("special", path))
    return cases


def command(kind: str, path: Path, good: dict[str, Path], out: Path) -> list[str]:
    if kind in ("textgrid", "lab", "align", "phones-json") or (kind == "special" and
                                                             path.suffix.lower() in (".textgrid", ".lab", ".align")):
        return ["animate-phones", str(path), "-o", str(out), "--model", "baseline"]
    if kind == "pose-table":
        return ["convert", str(good["animation-json"]), str(out) + ".csv", "--pose-table", str(path)]
    if kind == "glb":
        return ["convert", str(good["livelink"]), str(out) + ".glb", "--glb", str(path)]
    target = ".json" if kind in ("livelink",) or path.suffix == ".csv" else ".csv"
    return ["convert", str(path), str(out) + target]


def run_one(args: list[str], timeout: float, memory: int) -> dict:
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-c", CLI, *args], stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                                preexec_fn=limit, env=env)
        hung = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - start > timeout:
                hung = True
                os.kill(proc.pid, signal.SIGKILL)
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read().decode("utf-8", "replace")
    return {"rc": proc.returncode, "stderr": stderr, "hung": hung, "seconds": time.monotonic() - start,
            "max_rss_mb": usage.ru_maxrss / 1024}


def classify(result: dict, memory_mb: float) -> str:
    if result["hung"]:
        return "hang"
    if "Traceback" in result["stderr"]:
        return "over-memory" if "MemoryError" in result["stderr"] else "traceback"
    if result["rc"] < 0 or result["max_rss_mb"] > memory_mb:
        return "over-memory"
    lines = result["stderr"].splitlines()
    if result["rc"] == 2 and len(lines) == 1 and lines[0].startswith("error: "):
        return "error-line"
    if result["rc"] == 0:
        return "accepted"
    return "other"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=min(8, os.cpu_count() or 1))
    parser.add_argument("--timeout", type=float, default=10.0)
    parser.add_argument("--memory-mb", type=int, default=1024)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-seconds", type=float, default=900.0)
    parser.add_argument("--keep", type=Path, help="Keep the generated files in this folder.")
    parser.add_argument("--json", type=Path, help="Write the counts and examples here.")
    opts = parser.parse_args()

    rng = random.Random(opts.seed)
    folder = Path(tempfile.mkdtemp(prefix="vispeech-fuzz-")) if opts.keep is None else opts.keep
    folder.mkdir(parents=True, exist_ok=True)
    good = seeds(folder)
    kinds = [k for k in FORMATS if k != "special"]
    n_special = max(1, opts.count // 20)
    cases: list[tuple[str, Path]] = special_files(folder, rng, n_special)
    for i in range(opts.count - n_special):
        kind = kinds[i % len(kinds)]
        seed_path = good[kind]
        name = seed_path.name.replace("seed", f"fuzz{i}", 1)
        path = folder / name
        path.write_bytes(mutate(seed_path.read_bytes(), rng, kind))
        cases.append((kind, path))

    deadline = time.monotonic() + opts.max_seconds
    memory = opts.memory_mb * 1024 * 1024

    def work(index_case):
        index, (kind, path) = index_case
        if time.monotonic() > deadline:
            return kind, path, None
        out = folder / "out" / f"run{index}"
        result = run_one(command(kind, path, good, out), opts.timeout, memory)
        return kind, path, result

    started = time.monotonic()
    with ThreadPoolExecutor(opts.workers) as pool:
        results = list(pool.map(work, enumerate(cases)))
    elapsed = time.monotonic() - started

    per_kind: dict[str, Counter] = defaultdict(Counter)
    examples: dict[str, list] = defaultdict(list)
    total = Counter()
    worst_rss = worst_seconds = 0.0
    for kind, path, result in results:
        if result is None:
            total["skipped (time budget)"] += 1
            continue
        label = classify(result, opts.memory_mb)
        per_kind[kind][label] += 1
        total[label] += 1
        worst_rss = max(worst_rss, result["max_rss_mb"])
        worst_seconds = max(worst_seconds, result["seconds"])
        if label not in ("error-line", "accepted") and len(examples[label]) < 5:
            examples[label].append({"kind": kind, "file": str(path), "rc": result["rc"],
                                    "stderr": result["stderr"][-1500:]})
    print(f"{len(cases)} files, {elapsed:.0f} s with {opts.workers} workers, timeout {opts.timeout:g} s, "
          f"memory cap {opts.memory_mb} MB; slowest run {worst_seconds:.1f} s, peak RSS {worst_rss:.0f} MB")
    labels = ["error-line", "accepted", "traceback", "hang", "over-memory", "other"]
    print(f"{'format':16}" + "".join(f"{label:>13}" for label in labels))
    for kind in FORMATS:
        print(f"{kind:16}" + "".join(f"{per_kind[kind][label]:>13}" for label in labels))
    print(f"{'total':16}" + "".join(f"{total[label]:>13}" for label in labels))
    if total["skipped (time budget)"]:
        print(f"skipped for the time budget: {total['skipped (time budget)']}")
    for label, items in examples.items():
        print(f"\n--- {label} ({total[label]}), e.g. {items[0]['kind']} {items[0]['file']}:\n{items[0]['stderr']}")
    if opts.json:
        opts.json.write_text(json.dumps({"counts": dict(total), "per_format": {k: dict(v) for k, v in per_kind.items()},
                                         "examples": examples, "seconds": elapsed, "peak_rss_mb": worst_rss,
                                         "slowest_s": worst_seconds}, indent=1))
    if opts.keep is None:
        shutil.rmtree(folder, ignore_errors=True)
    bad = sum(total[label] for label in ("traceback", "hang", "over-memory", "other"))
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
