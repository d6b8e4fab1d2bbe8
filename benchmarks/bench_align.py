"""Forced alignment on GRID: speed, and word boundaries against GRID's own ``.align`` timings.

    python benchmarks/bench_align.py [GRID_DIR] [--jobs N] [--limit N]

Aligns every utterance afresh (a temporary cache), then prints the time per utterance and
the absolute difference in ms between pocketsphinx's word starts/ends and the corpus's.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from vispeech.corpus import align_corpus, read_grid

DEFAULT_GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", nargs="?", type=Path, default=DEFAULT_GRID)
    parser.add_argument("--jobs", type=int, default=1, help="alignment processes")
    parser.add_argument("--limit", type=int, default=None, help="align only the first N utterances")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as cache:
        t0 = time.perf_counter()
        corpus = read_grid(args.grid, cache=cache)
        read_seconds = time.perf_counter() - t0
        if args.limit:
            corpus.utterances = corpus.utterances[: args.limit]
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as failures:
            warnings.simplefilter("always")
            align_corpus(corpus, jobs=args.jobs)
        align_seconds = time.perf_counter() - t0

    starts, ends = [], []
    for utterance in corpus:
        if utterance.phones is None:
            continue
        aligned = utterance.phones.words
        if [w.text for w in aligned] != [w.text for w in utterance.words]:
            raise SystemExit(f"{utterance.id}: aligned words differ from the .align words")
        starts += [abs(a.start - g.start) for a, g in zip(aligned, utterance.words, strict=True)]
        ends += [abs(a.end - g.end) for a, g in zip(aligned, utterance.words, strict=True)]
    starts_ms, ends_ms = np.array(starts) * 1000, np.array(ends) * 1000
    both = np.concatenate([starts_ms, ends_ms])
    n_aligned = sum(u.phones is not None for u in corpus)

    print(f"corpus: {corpus.name}, {len(corpus)} utterances, {corpus.duration:.0f} s of audio "
          f"(read in {read_seconds:.1f} s)")
    print(f"aligned: {n_aligned}, failed: {len(failures)}, jobs: {args.jobs}")
    per_utterance_ms = align_seconds / max(len(corpus), 1) * 1000
    print(f"alignment time: {align_seconds:.1f} s total, {per_utterance_ms:.0f} ms per utterance, "
          f"{corpus.duration / align_seconds:.0f}x real time")
    print(f"word boundaries vs GRID .align ({len(starts_ms)} words):")
    for name, values in (("starts", starts_ms), ("ends", ends_ms), ("both", both)):
        print(f"  {name:6s} mean abs error {values.mean():5.1f} ms, median {np.median(values):5.1f} ms, "
              f"95th percentile {np.percentile(values, 95):5.1f} ms, within 60 ms {np.mean(values <= 60) * 100:5.1f} %")


if __name__ == "__main__":
    main()
