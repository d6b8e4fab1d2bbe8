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
from pathlib import Path

import numpy as np

from vispeech.frontends.audio import AudioClip
from vispeech.frontends.espeak import synthesize
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_AUDIO_MODEL, DEFAULT_MODEL, animate, animate_audio

SENTENCES = Path(__file__).resolve().parents[1] / "tests" / "data"
FPS = 30.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", nargs="+", default=[DEFAULT_AUDIO_MODEL], help="audio models (names or folders)")
    parser.add_argument("--phone-model", default=DEFAULT_MODEL)
    parser.add_argument("--rates", type=float, nargs="+", default=[0.8, 1.0, 1.3])
    args = parser.parse_args()

    phone_model = load_model(args.phone_model)
    audio_models = {name: load_model(name) for name in args.model}
    print(f"{'model':<22} {'lang':<4} {'rate':>4} {'sentences':>9} {'pooled r':>8} {'mean r':>7}")
    for language in ("en", "sv"):
        sentences = [s.strip() for s in (SENTENCES / f"sentences_{language}.txt").read_text(encoding="utf-8")
                     .splitlines() if s.strip()]
        for rate in args.rates:
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
                print(f"{name:<22} {language:<4} {rate:>4.1f} {len(sentences):>9} {pooled:>8.3f} "
                      f"{np.nanmean(per_sentence):>7.3f}", flush=True)


if __name__ == "__main__":
    main()
