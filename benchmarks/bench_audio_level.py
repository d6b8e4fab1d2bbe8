"""Audio models at other recording levels: grid_s1 utterances gained by −30 to +6 dB.

    python benchmarks/bench_audio_level.py [--models grid-audio-cnn grid-audio-encdec ...]
                                           [--levels -30 -20 -10 -5 0 6] [--split validation]

A user's microphone, a voice service or a mixing desk gives speech at any level; the models
learned from one recording level. Every utterance of the split (validation by default: no model
trained on it) is gained by each ``--levels`` dB (clipped at full scale, as a recording would
be) and animated alone by each model, raw (no post-processing). Prints jawOpen r (mean over
utterances, on each utterance's scored frames as ``vispeech evaluate`` takes them) by level,
and each model's ``level_range`` (the training clips' levels, dB) where it matches levels
(``match_level``, docs/audio.md "Recording level"), beside the levels of the split's utterances.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from bench_long_clips import GRID, r_of, split_utterances

from vispeech.frontends.audio import AudioClip
from vispeech.frontends.features import SAMPLE_RATE, power_spectrogram, speech_level
from vispeech.models.registry import load_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["grid-audio-cnn", "grid-audio-encdec"])
    parser.add_argument("--levels", nargs="+", type=float, default=[-30, -20, -10, -5, 0, 6], help="gains (dB)")
    parser.add_argument("--split", default="validation", choices=("validation", "test", "train"))
    parser.add_argument("--corpus", type=Path, default=GRID)
    args = parser.parse_args()
    utterances = split_utterances(args.corpus, args.split)
    clips = []
    for utterance in utterances:
        samples, rate = utterance.load_audio()
        clips.append(AudioClip.from_array(samples, rate))
    levels = [speech_level(power_spectrogram(clip.resampled(SAMPLE_RATE).samples)) for clip in clips]
    print(f"{len(utterances)} grid_s1 {args.split} utterances, levels {min(levels):.1f} to {max(levels):.1f} dB "
          f"(median {np.median(levels):.1f}); jawOpen r (raw, mean over utterances) by gain")
    print(f"{'model':32}" + "".join(f"{level:>+8g}" for level in args.levels) + "   level_range (dB)")
    for name in args.models:
        model = load_model(name)
        row = []
        for gain in args.levels:
            scores = []
            for utterance, clip in zip(utterances, clips):
                louder = np.clip(clip.samples * np.float32(10 ** (gain / 20)), -1.0, 1.0)
                jaw = model.predict(AudioClip.from_array(louder, clip.sample_rate), utterance.track.fps)["jawOpen"]
                n = min(len(jaw), utterance.track.n_frames)
                scores.append(r_of(jaw[:n], utterance, slice(0, n)))
            row.append(float(np.mean(scores)))
        span = getattr(getattr(model, "encoding_", None), "level_range", None)
        where = f"{span[0]:.1f} to {span[1]:.1f}" if span else "—"
        print(f"{name:32}" + "".join(f"{r:8.3f}" for r in row) + f"   {where}", flush=True)


if __name__ == "__main__":
    main()
