"""Audio models on a real voice moved towards other speakers: GRID audio pitch- and formant-shifted.

    python benchmarks/bench_audio_shift.py [--split validation] [--model grid-audio-encdec grid-audio-cnn ...]
                                           [--shifts 0 -3 3 5] [--corpus ../shared/data/grid_s1]

Every utterance of the split is shifted by each number of semitones with librosa's
``effects.pitch_shift`` (phase vocoder and resampling: the pitch and the whole spectral
envelope move together, as between a longer and a shorter vocal tract; +3 to +5 is roughly
a male voice made female) and animated by each audio model, raw (no post-processing); printed
is the jawOpen Pearson r pooled over all frames against the speaker's tracked jawOpen. A proxy
for other speakers that keeps real speech, beside ``bench_audio_voices.py``'s synthetic
espeak-ng voices. The default split is validation, on which models are chosen.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from vispeech.corpus import CorpusWarning, read_grid
from vispeech.frontends.audio import AudioClip
from vispeech.models.registry import load_model

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--corpus", type=Path, default=ROOT.parent / "shared" / "data" / "grid_s1")
    parser.add_argument("--split", default="validation", choices=["train", "validation", "test"])
    parser.add_argument("--model", nargs="+", default=["grid-audio-encdec", "grid-audio-cnn"],
                        help="audio models: shipped names or saved folders")
    parser.add_argument("--shifts", nargs="+", type=float, default=[0, -3, 3, 5], help="semitones")
    args = parser.parse_args()

    import librosa

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        utterances = read_grid(args.corpus).split(args.split)
    models = {name: load_model(name) for name in args.model}
    pairs: dict[tuple[str, float], tuple[list, list]] = {(m, s): ([], []) for m in models for s in args.shifts}
    for utterance in utterances:
        audio, rate = utterance.load_audio()
        truth, fps = utterance.track["jawOpen"], utterance.track.fps
        for shift in args.shifts:
            shifted = audio if shift == 0 else librosa.effects.pitch_shift(audio, sr=rate, n_steps=shift,
                                                                           res_type="soxr_hq")
            clip = AudioClip.from_array(np.asarray(shifted, dtype=np.float32), rate)
            for name, model in models.items():
                predicted = model.predict(clip, fps)["jawOpen"]
                n = min(len(predicted), len(truth))
                pairs[name, shift][0].append(predicted[:n])
                pairs[name, shift][1].append(truth[:n])
    print(f"{args.split} split, {len(utterances)} utterances: jawOpen r pooled over frames (raw output), "
          "by shift in semitones")
    width = max(len(m) for m in models) + 2
    print("model".ljust(width) + "".join(f"{s:>8g}" for s in args.shifts))
    for name in models:
        row = [np.corrcoef(np.concatenate(pairs[name, s][0]), np.concatenate(pairs[name, s][1]))[0, 1]
               for s in args.shifts]
        print(name.ljust(width) + "".join(f"{r:8.3f}" for r in row))


if __name__ == "__main__":
    main()
