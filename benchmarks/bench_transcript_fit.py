"""Transcript fit (``vispeech.frontends.align.transcript_fit``) of true and wrong transcripts.

    python benchmarks/bench_transcript_fit.py [--choose] [--pairs N] [--dev-eval]

A wrong pair is an utterance's audio with the transcript of the next utterance of a random sample.
``--choose`` measures the 100 grid_s1 utterances ``MIN_FIT`` was chosen on (seed 0); otherwise
``--pairs`` others (20 by default; 0 for none) are checked against ``MIN_FIT``, and with
``--dev-eval`` every utterance of ``../shared/data/dev_eval`` as well (for measuring only:
never choose the threshold on it). Prints the fits' spread and how many true transcripts are taken and wrong ones
refused.
"""

from __future__ import annotations

import argparse
import csv
import random
import time
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.align import MIN_FIT, in_dictionary, normalize_transcript, transcript_fit
from vispeech.frontends.audio import AudioClip

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CHOSEN_ON = 100
"""How many grid_s1 utterances (a seed-0 sample) MIN_FIT was chosen on."""


def sentences(folder: Path) -> dict[str, str]:
    with open(folder / "sentences.tsv", encoding="utf-8") as f:
        return {row["id"]: row["text"] for row in csv.DictReader(f, delimiter="\t")}


def fits(folder: Path, ids: list[str], texts: dict[str, str]) -> dict[str, list[float]]:
    """The fit of each utterance's own transcript and of the next one's."""
    found: dict[str, list[float]] = {"true": [], "wrong": []}
    for i, name in enumerate(ids):
        clip = AudioClip.read(folder / "utterances" / f"{name}.flac")
        for kind, text in (("true", texts[name]), ("wrong", texts[ids[(i + 1) % len(ids)]])):
            if all(in_dictionary(w) for w in normalize_transcript(text)):
                try:
                    found[kind].append(transcript_fit(clip, text))
                except VispeechError:  # no path through the audio: refused all the same
                    found[kind].append(-np.inf)
    return found


def report(label: str, found: dict[str, list[float]], every: bool = False) -> None:
    for kind, values in found.items():
        if every:
            print(f"{label} {kind} fits:", " ".join(f"{v:.1f}" for v in sorted(values)))
        v = np.array(values)
        kept = np.sum(v >= MIN_FIT) if kind == "true" else np.sum(~(v >= MIN_FIT))
        verb = "taken" if kind == "true" else "refused"
        print(
            f"{label} {kind:5s} n={len(v):3d} fit min {np.nanmin(v):6.1f} median {np.nanmedian(v):6.1f} "
            f"max {np.nanmax(v):6.1f}  {verb} at MIN_FIT {MIN_FIT:g}: {kept}/{len(v)}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--choose", action="store_true", help="the utterances MIN_FIT was chosen on")
    parser.add_argument("--pairs", type=int, default=20)
    parser.add_argument("--dev-eval", action="store_true")
    args = parser.parse_args()
    grid = DATA / "grid_s1"
    texts = sentences(grid)
    chosen = random.Random(0).sample(sorted(texts), CHOSEN_ON)
    others = sorted(set(texts) - set(chosen))
    ids = chosen if args.choose else random.Random(1).sample(others, args.pairs)
    t0 = time.perf_counter()
    if ids:
        report("grid_s1", fits(grid, ids, texts), every=args.choose)
    if args.dev_eval:
        for name in ("grid_s4", "natural"):
            folder = DATA / "dev_eval" / name
            texts = sentences(folder)  # shuffled: GRID's neighbouring ids share most of their words
            report(f"dev_eval/{name}", fits(folder, random.Random(0).sample(sorted(texts), len(texts)), texts))
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
