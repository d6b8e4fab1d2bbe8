"""Speed of the data-free control models (phones → track) and of post-processing.

    python benchmarks/bench_models.py [--sentences N] [--fps FPS] [--seed S]

Builds N random ~3 s sentences (half Swedish, half English: silence, then syllables of
random consonants and vowels of 40–160 ms, then silence), predicts each with every model
on one thread and prints frames per second per model, and for post-processing.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.models.registry import create_model
from vispeech.phonetics.inventory import get_inventory, is_silence
from vispeech.postprocess import postprocess

DATA_FREE = ("baseline", "beskow-rules", "cohen-massaro", "ohman")


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sentences", type=int, default=200)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    sentences = [random_sentence(rng, ("sv", "en")[i % 2]) for i in range(args.sentences)]
    frames = sum(s.n_frames(args.fps) for s in sentences)
    print(f"{len(sentences)} sentences, {frames} frames at {args.fps:g} fps")
    for name in DATA_FREE:
        model = create_model(name)
        model.predict(sentences[0], args.fps)  # warm-up
        t0 = time.perf_counter()
        tracks = [model.predict(s, args.fps) for s in sentences]
        seconds = time.perf_counter() - t0
        print(f"{name:>15}: {frames / seconds:12,.0f} frames/s  ({1e3 * seconds / len(sentences):.2f} ms/sentence)")
    t0 = time.perf_counter()
    for track, sentence in zip(tracks, sentences):
        postprocess(track, sentence)
    seconds = time.perf_counter() - t0
    print(f"{'postprocess':>15}: {frames / seconds:12,.0f} frames/s  ({1e3 * seconds / len(sentences):.2f} ms/sentence)")


if __name__ == "__main__":
    main()
