"""``vispeech batch`` on thousands of lines: speed, reruns and kills.

    python benchmarks/bench_batch.py [--lines 2000] [--jobs 2] [--single 40] [--keep DIR]

Makes a manifest of ``--lines`` English and Swedish sentences (half each, built from word
lists with a fixed seed), then, all as real ``vispeech`` processes:

1. ``vispeech batch`` of the whole job, text → all five outputs, on ``--jobs`` workers: lines
   per second, wall time including start-up;
2. one ``vispeech say`` process per line for the first ``--single`` lines (the way a pipeline
   without batches runs), one at a time as a shell loop runs them and ``--jobs`` at a time:
   lines per second, and the batch's speed-up over each (goal ≥ 20×);
3. a rerun after changing 10 lines: it must write exactly those 10 and leave the rest;
4. a fresh batch killed (SIGKILL) halfway, then rerun: every line must end written once,
   complete, with no half-written folder or leftover.

Prints a table and exits non-zero if 3 or 4 fail.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

EN = {
    "who": ["The captain", "My sister", "Every pilot", "The old baker", "Our guide", "A tired robot", "The mayor"],
    "does": ["found", "painted", "carried", "borrowed", "mapped", "opened", "remembered"],
    "what": ["a blue boat", "the broken map", "five paper lamps", "my father's watch", "the big red box"],
    "when": ["before dawn.", "at the market.", "near the farm.", "after the storm.", "on Monday morning."],
}
SV = {
    "who": ["Kaptenen", "Min syster", "Varje pilot", "Den gamle bagaren", "Vår guide", "En trött robot"],
    "does": ["hittade", "målade", "bar", "lånade", "öppnade", "mindes"],
    "what": ["en blå båt", "den trasiga kartan", "fem papperslampor", "min pappas klocka", "den stora lådan"],
    "when": ["före gryningen.", "på marknaden.", "vid gården.", "efter stormen.", "på måndag morgon."],
}


def make_lines(n: int, seed: int = 0) -> list[dict]:
    rng = random.Random(seed)
    lines = []
    for i in range(n):
        lang, words = ("en", EN) if i % 2 == 0 else ("sv", SV)
        text = " ".join(rng.choice(words[k]) for k in ("who", "does", "what", "when"))
        lines.append({"id": f"line{i:05d}", "text": f"{text}", "language": lang})
    return lines


def write_job(path: Path, lines: list[dict]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=["id", "text", "lang"])
        writer.writeheader()
        writer.writerows(lines)


def vispeech(*args: str) -> list[str]:
    return [sys.executable, "-c", "from vispeech.cli import main; main()", *args]


def batch(job: Path, out: Path, jobs: int) -> tuple[float, list[dict]]:
    start = time.perf_counter()
    result = subprocess.run(vispeech("batch", str(job), "-o", str(out), "-j", str(jobs), "-q"),
                            capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if result.returncode != 0:
        sys.exit(f"vispeech batch failed ({result.returncode}): {result.stderr.strip()[-2000:]}")
    index = [json.loads(line) for line in (out / "index.jsonl").read_text().splitlines()]
    return seconds, index


def complete(out: Path) -> set[str]:
    """Line folders holding their record (not the hidden folders a run is writing)."""
    return {p.parent.name for p in out.glob("*/batch.json") if not p.parent.name.startswith(".")}


def statuses(index: list[dict]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for row in index:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lines", type=int, default=2000)
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--single", type=int, default=40, help="lines run as one `vispeech say` process each")
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="vispeech-bench-batch-"))
    work.mkdir(parents=True, exist_ok=True)
    ok = True
    try:
        lines = make_lines(args.lines)
        job = work / "job.csv"
        write_job(job, lines)
        print(f"{args.lines} lines ({sum(x['lang'] == 'en' for x in lines)} en, "
              f"{sum(x['lang'] == 'sv' for x in lines)} sv), {args.jobs} workers, {os.cpu_count()} cores; work in {work}")

        # 1. the whole batch
        seconds, index = batch(job, work / "out", args.jobs)
        counts = statuses(index)
        batch_rate = args.lines / seconds
        print(f"batch:            {seconds:8.1f} s  {batch_rate:7.2f} lines/s  {counts}")
        ok &= counts.get("written") == args.lines

        # 2. one process per line: one at a time, then --jobs at a time
        single = lines[: args.single]

        def say(line: dict) -> None:
            subprocess.run(vispeech("say", line["text"], "--language", line["language"], "-o", str(work / "single" / line["id"])),
                           check=True, capture_output=True)

        for concurrency in sorted({1, args.jobs}):
            start = time.perf_counter()
            with ThreadPoolExecutor(concurrency) as pool:
                list(pool.map(say, single))
            single_seconds = time.perf_counter() - start
            single_rate = len(single) / single_seconds
            print(f"process per line, {concurrency} at a time: {single_seconds:6.1f} s  {single_rate:7.2f} lines/s  "
                  f"({len(single)} lines); batch speed-up {batch_rate / single_rate:5.1f} x (goal 20 x)")
        same = all((work / "single" / x["id"] / "animation.csv").read_bytes()
                   == (work / "out" / x["id"] / "animation.csv").read_bytes() for x in single)
        print(f"batch files equal the single commands': {same}")
        ok &= same

        # 3. change 10 lines, rerun
        changed = set(random.Random(1).sample(range(args.lines), 10))
        for i in changed:
            lines[i] = {**lines[i], "text": lines[i]["text"].replace(".", ", again.")}
        write_job(job, lines)
        seconds, index = batch(job, work / "out", args.jobs)
        written = {row["id"] for row in index if row["status"] == "written"}
        exact = written == {lines[i]["id"] for i in changed} and statuses(index).get("unchanged") == args.lines - 10
        print(f"rerun, 10 changed: {seconds:7.1f} s  {statuses(index)}  redid exactly those 10: {exact}")
        ok &= exact

        # 4. kill halfway, rerun
        out = work / "killed"
        process = subprocess.Popen(vispeech("batch", str(job), "-o", str(out), "-j", str(args.jobs), "-q"),
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        while process.poll() is None:
            done = len(complete(out)) if out.is_dir() else 0
            if done >= args.lines // 2:
                break
            time.sleep(0.2)
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        complete_before = complete(out)
        seconds, index = batch(job, out, args.jobs)
        counts = statuses(index)
        unchanged = {row["id"] for row in index if row["status"] == "unchanged"}
        folders = [p.name for p in out.iterdir() if p.is_dir()]
        leftovers = [p.name for p in out.iterdir() if p.name.startswith(".vispeech-")]
        intact = (unchanged == complete_before and counts.get("written", 0) + len(unchanged) == args.lines
                  and len(folders) == args.lines and not leftovers
                  and all(len(list((out / f).iterdir())) == 6 for f in folders))
        print(f"killed after {len(complete_before)} lines, rerun: {seconds:.1f} s  {counts}  "
              f"nothing lost or duplicated: {intact}")
        ok &= intact
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
