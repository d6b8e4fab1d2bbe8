"""Speed of every runnable model: phones → track, and text → audio + track.

    python benchmarks/bench_models.py [--sentences N] [--fps FPS] [--seed S]

1. phones → track: builds N random ~3 s sentences (half Swedish, half English: silence,
   then syllables of random consonants and vowels of 40–160 ms, then silence) and animates
   each with every model of ``vispeech models`` (:func:`vispeech.pipeline.animate`: the
   model and the post-processing it recommends), printing frames per second of output,
   and the model's prediction alone; the best of ``--passes`` passes counts (the machine's
   other work only slows a pass down). Target: ``grid-tdnn`` ≥ 20,000 frames/s with
   post-processing (≤ 4.5 ms per 3-s sentence at 30 fps).
2. text → audio + track: speaks N real sentences (half Swedish, half English: the test
   sentences and, when ../shared is there, GRID's transcripts) through
   :func:`vispeech.pipeline.speak` (espeak-ng + model + post-processing) with every model.

Runs in one process on one core (BLAS threads pinned to 1; pin the process with taskset -c 0).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import gc  # noqa: E402
import itertools  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from vispeech.alignment.phones import Phone, PhoneSequence  # noqa: E402
from vispeech.models.registry import RUNNABLE, load_model  # noqa: E402
from vispeech.phonetics.inventory import get_inventory, is_silence  # noqa: E402
from vispeech.pipeline import animate, speak  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

TARGET = {"grid-tdnn": 20_000}
"""Frames per second of phones → track with post-processing that a model must reach."""


def random_sentence(rng: np.random.Generator, language: str, seconds: float = 3.0) -> PhoneSequence:
    inventory = get_inventory(language)
    vowels = sorted(inventory.vowels)
    consonants = [s for s in inventory.symbols if s not in inventory.vowels and not is_silence(s)]
    phones, t = [Phone("sil", 0.0, 0.2)], 0.2
    while t < seconds - 0.3:
        for symbol in [*rng.choice(consonants, rng.integers(0, 3)), rng.choice(vowels)]:
            duration = float(rng.uniform(0.04, 0.16))
            phones.append(Phone(str(symbol), t, t + duration, stress=int(rng.integers(0, 2))))
            t += duration
    phones.append(Phone("sil", t, t + 0.2))
    return PhoneSequence(phones, language)


def best_pass(run, sentences: list, passes: int) -> float:
    """Seconds of the fastest of ``passes`` runs over every sentence (the first one warms caches
    too), with the garbage collector paused while a pass runs, as :mod:`timeit` does."""
    times = []
    for _ in range(passes):
        gc.collect()
        gc.disable()
        try:
            t0 = time.perf_counter()
            for sentence in sentences:
                run(sentence)
            times.append(time.perf_counter() - t0)
        finally:
            gc.enable()
    return min(times)


def real_sentences(n: int) -> list[tuple[str, str]]:
    """``n`` (language, text) pairs, alternating Swedish and English."""
    def lines(path: Path) -> list[str]:
        return [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]

    swedish = lines(ROOT / "tests" / "data" / "sentences_sv.txt")
    english = lines(ROOT / "tests" / "data" / "sentences_en.txt")
    grid = ROOT.parent / "shared" / "data" / "grid_s1" / "sentences.tsv"
    if grid.is_file():
        english += [line.split("\t", 1)[1] for line in lines(grid)[1:]]
    pairs = zip(itertools.cycle(swedish), itertools.cycle(english))
    return [item for sv, en in itertools.islice(pairs, (n + 1) // 2) for item in (("sv", sv), ("en", en))][:n]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sentences", type=int, default=200)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--passes", type=int, default=3, help="passes over the sentences per model; the best counts")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    sentences = [random_sentence(rng, ("sv", "en")[i % 2]) for i in range(args.sentences)]
    frames = sum(s.n_frames(args.fps) for s in sentences)
    print(f"{len(sentences)} sentences, {frames} frames at {args.fps:g} fps")
    warm_up = load_model(RUNNABLE[0])
    for sentence in sentences:  # untimed: the first seconds of a process run slower (page faults, clocks)
        animate(sentence, warm_up, args.fps)
    print(f"{'model':>22}  {'with post-processing':>22}  {'prediction alone':>18}   (best of {args.passes} passes)")
    for name in RUNNABLE:
        model = load_model(name)
        whole = best_pass(lambda s: animate(s, model, args.fps), sentences, args.passes)
        alone = best_pass(lambda s: model.predict(s, args.fps), sentences, args.passes)
        target = f"  (target {TARGET[name]:,}: {'met' if frames / whole >= TARGET[name] else 'NOT met'})" \
            if name in TARGET else ""
        print(f"{name:>22}  {frames / whole:10,.0f} frames/s {1e3 * whole / len(sentences):5.2f} ms"
              f"  {frames / alone:10,.0f} frames/s{target}")

    texts = real_sentences(args.sentences)
    print(f"\ntext -> audio + track, {len(texts)} sentences (espeak-ng + model + post-processing)")
    for name in RUNNABLE:
        model = load_model(name)
        t0 = time.perf_counter()
        utterances = [speak(text, language, model=model, fps=args.fps) for language, text in texts]
        seconds = time.perf_counter() - t0
        n_frames = sum(u.track.n_frames for u in utterances)
        audio = sum(len(u.audio) / u.sample_rate for u in utterances)
        print(f"{name:>15}: {n_frames / seconds:12,.0f} frames/s  ({1e3 * seconds / len(texts):.1f} ms/sentence, "
              f"{audio / seconds:.0f}x real time)")


if __name__ == "__main__":
    main()
