"""The audio front ends on GRID: word boundaries of both aligners, phone errors of recognition.

    python benchmarks/bench_audio_frontends.py [GRID_DIR] [--limit N]

On ``--limit`` utterances spread evenly over the corpus (default 100; 0 for all), prints for
pocketsphinx forced alignment and for DTW against espeak-ng (English) the absolute difference
in ms between their word starts/ends and GRID's own ``.align`` timings, and for phone
recognition from the audio alone its phone error rate against the pocketsphinx alignment
(substitutions, insertions and deletions over the aligned phones) and the start and end
differences of the phones both agree on; with the time each takes per utterance.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from vispeech.alignment.formats import read_word_alignment
from vispeech.errors import VispeechError
from vispeech.frontends.align import align
from vispeech.frontends.audio import read_audio
from vispeech.frontends.recognize import match_phones, recognize_phones

DEFAULT_GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", nargs="?", type=Path, default=DEFAULT_GRID)
    parser.add_argument("--limit", type=int, default=100, help="utterances, spread over the corpus (0: all)")
    args = parser.parse_args()

    lines = (args.grid / "sentences.tsv").read_text(encoding="utf-8").splitlines()[1:]  # after the header
    texts = dict(line.split("\t", 1) for line in lines if "\t" in line)
    ids = sorted(texts)
    if args.limit:
        ids = [ids[k] for k in np.linspace(0, len(ids) - 1, min(args.limit, len(ids))).round().astype(int)]

    boundaries: dict[str, list[float]] = {"pocketsphinx": [], "dtw": []}
    seconds = {"pocketsphinx": 0.0, "dtw": 0.0, "recognition": 0.0}
    failures = {"pocketsphinx": 0, "dtw": 0, "recognition": 0}
    errors = n_reference = n_hypothesis = 0
    matched_starts: list[float] = []
    matched_ends: list[float] = []
    for utterance in ids:
        folder = args.grid / "utterances"
        samples, rate = read_audio(folder / f"{utterance}.flac")
        reference = read_word_alignment(folder / f"{utterance}.align")
        aligned = {}
        for method in ("pocketsphinx", "dtw"):
            t0 = time.perf_counter()
            try:
                aligned[method] = align(samples, rate, texts[utterance], "en", method=method)
            except VispeechError as exc:
                failures[method] += 1
                print(f"{utterance}: {method}: {exc}")
                continue
            finally:
                seconds[method] += time.perf_counter() - t0
            words = aligned[method].words
            if [w.text.lower() for w in words] != [w.text for w in reference]:
                failures[method] += 1
                print(f"{utterance}: {method}: words {[w.text for w in words]} differ from the .align words")
                continue
            for a, g in zip(words, reference, strict=True):
                boundaries[method] += [abs(a.start - g.start), abs(a.end - g.end)]
        t0 = time.perf_counter()
        try:
            heard = recognize_phones(samples, rate)
        except VispeechError as exc:
            failures["recognition"] += 1
            print(f"{utterance}: recognition: {exc}")
            continue
        finally:
            seconds["recognition"] += time.perf_counter() - t0
        if "pocketsphinx" in aligned:
            edits, pairs = match_phones(aligned["pocketsphinx"], heard)
            errors += edits
            n_reference += sum(not p.is_silence for p in aligned["pocketsphinx"])
            n_hypothesis += sum(not p.is_silence for p in heard)
            matched_starts += [abs(r.start - h.start) for r, h in pairs]
            matched_ends += [abs(r.end - h.end) for r, h in pairs]

    n = len(ids)
    print(f"GRID {args.grid.name}: {n} utterances")
    for method, label in (("pocketsphinx", "pocketsphinx alignment"), ("dtw", "DTW alignment (espeak-ng en-us)")):
        print(f"{label}: {seconds[method] / n * 1000:.0f} ms per utterance, {failures[method]} failed")
        _report("word boundaries (starts and ends) vs GRID .align", boundaries[method])
    print(f"phone recognition: {seconds['recognition'] / n * 1000:.0f} ms per utterance, "
          f"{failures['recognition']} failed")
    print(f"  phone error rate vs the pocketsphinx alignment {errors / max(n_reference, 1) * 100:.1f} % "
          f"({errors} edits, {n_reference} aligned phones, {n_hypothesis} recognised)")
    print(f"  matched phones: {len(matched_starts)} ({len(matched_starts) / max(n_reference, 1) * 100:.0f} % "
          f"of the aligned)")
    _report("starts of matched phones", matched_starts)
    _report("ends of matched phones", matched_ends)


def _report(what: str, seconds: list[float]) -> None:
    if not seconds:
        print(f"  {what}: none")
        return
    ms = np.array(seconds) * 1000
    print(f"  {what}, {len(ms)}: mean abs error {ms.mean():5.1f} ms, median {np.median(ms):5.1f} ms, "
          f"95th percentile {np.percentile(ms, 95):5.1f} ms, within 60 ms {np.mean(ms <= 60) * 100:5.1f} %")


if __name__ == "__main__":
    main()
