"""Audio models on voices they never heard: espeak-ng's English and Swedish voices.

    python benchmarks/bench_audio_voices.py [--model grid-audio-cnn ...] [--phone-model grid-tdnn]
                                           [--rates 0.8 1.0 1.3]

For every acceptance sentence (tests/data/sentences_en.txt and sentences_sv.txt) at each
speaking rate, espeak-ng synthesises the audio with its phone timings; the phone model
animates the timed phones (the reference: it needs no audio) and each audio model animates
the audio alone. Prints jawOpen Pearson r between the two per language and rate, pooled over
the frames of all sentences and as the mean of per-sentence r, both post-processed as
``vispeech say`` and ``vispeech animate`` do, at 30 fps.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from vispeech.frontends.audio import AudioClip
from vispeech.frontends.espeak import synthesize
from vispeech.models.contract import Estimator
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_AUDIO_MODEL, DEFAULT_MODEL, animate, animate_audio

SENTENCES = Path(__file__).resolve().parents[1] / "tests" / "data"
FPS = 30.0
LANGUAGES = ("en", "sv")
RATES = (0.8, 1.0, 1.3)


def voice_scores(audio_models: Mapping[str, Estimator], phone_model: Estimator,
                 rates: Sequence[float] = RATES) -> Iterator[dict]:
    """Per language of :data:`LANGUAGES`, rate and audio model (by label), as computed: ``model``,
    ``language``, ``rate``, ``sentences``, ``pooled_r`` and ``mean_r`` (jawOpen r against the
    phone model on espeak-ng's phone timings)."""
    for language in LANGUAGES:
        sentences = [s.strip() for s in (SENTENCES / f"sentences_{language}.txt").read_text(encoding="utf-8")
                     .splitlines() if s.strip()]
        for rate in rates:
            speeches = [synthesize(text, language, rate=rate) for text in sentences]
            references = [animate(s.phones, phone_model, FPS)["jawOpen"] for s in speeches]
            for name, model in audio_models.items():
                pooled_a, pooled_b, per_sentence = [], [], []
                for speech, reference in zip(speeches, references):
                    clip = AudioClip.from_array(speech.audio, speech.sample_rate)
                    jaw = animate_audio(clip, model, FPS)["jawOpen"]
                    n = min(len(jaw), len(reference))
                    pooled_a.append(jaw[:n])
                    pooled_b.append(reference[:n])
                    per_sentence.append(np.corrcoef(jaw[:n], reference[:n])[0, 1])
                pooled = np.corrcoef(np.concatenate(pooled_a), np.concatenate(pooled_b))[0, 1]
                yield {"model": name, "language": language, "rate": rate, "sentences": len(sentences),
                       "pooled_r": float(pooled), "mean_r": float(np.nanmean(per_sentence))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", nargs="+", default=[DEFAULT_AUDIO_MODEL], help="audio models (names or folders)")
    parser.add_argument("--phone-model", default=DEFAULT_MODEL)
    parser.add_argument("--rates", type=float, nargs="+", default=list(RATES))
    args = parser.parse_args()

    audio_models = {name: load_model(name) for name in args.model}
    print(f"{'model':<22} {'lang':<4} {'rate':>4} {'sentences':>9} {'pooled r':>8} {'mean r':>7}")
    for row in voice_scores(audio_models, load_model(args.phone_model), args.rates):
        print(f"{row['model']:<22} {row['language']:<4} {row['rate']:>4.1f} {row['sentences']:>9} "
              f"{row['pooled_r']:>8.3f} {row['mean_r']:>7.3f}", flush=True)


if __name__ == "__main__":
    main()
