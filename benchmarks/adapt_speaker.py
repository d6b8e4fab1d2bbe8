"""Speaker adaptation on a simulated new speaker: a shipped network adapted on 50 utterances.

    python benchmarks/adapt_speaker.py [--model grid-tdnn|grid-audio-cnn] [--train 50] [--width 1.6]
                                       [--jaw 0.06] [--epochs 60]

No second speaker's tracks are at hand, so one is simulated: every grid_s1 track has its mouth
widened (mouthStretch and mouthSmile times ``--width``) and its jaw lowered (jawOpen plus
``--jaw``, clipped to 1). Three models then predict the transformed test split (83 utterances,
no post-processing):
- the shipped ``--model`` (a phone or an audio network) as it is;
- that model adapted on the first ``--train`` transformed training utterances
  (``vispeech train --from MODEL``: warm start, early stopping on 15 validation utterances);
- the same architecture trained from scratch on those utterances.

Prints RMSE (% of each channel's range) and Pearson r per channel.
"""

from __future__ import annotations

import argparse
import copy
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from vispeech.corpus import CorpusWarning, align_corpus, read_grid
from vispeech.evaluation.report import evaluate_models
from vispeech.models.contract import clone
from vispeech.models.registry import load_model
from vispeech.motion.track import Track

GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"
CHANNELS = ("jawOpen", "mouthClose", "mouthStretchLeft", "mouthSmileLeft")


def new_speaker(track: Track, width: float, jaw: float) -> Track:
    """``track`` as a speaker with a wider mouth and a lower jaw would make it."""
    values = np.array(track.values, copy=True)
    for channel in ("mouthStretchLeft", "mouthStretchRight", "mouthSmileLeft", "mouthSmileRight"):
        if channel in track.channels:
            values[:, track.index(channel)] *= width
    if "jawOpen" in track.channels:
        values[:, track.index("jawOpen")] += jaw
    return Track(np.clip(values, 0.0, 1.0), track.channels, track.fps, track.start_time)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="grid-tdnn")
    parser.add_argument("--train", type=int, default=50)
    parser.add_argument("--validation", type=int, default=15)
    parser.add_argument("--width", type=float, default=1.6)
    parser.add_argument("--jaw", type=float, default=0.06)
    parser.add_argument("--epochs", type=int, default=60)
    args = parser.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        corpus = read_grid(GRID)
    train = list(corpus.split("train"))[:args.train]
    validation = list(corpus.split("validation"))[:args.validation]
    test = list(corpus.split("test"))
    small = replace(corpus, utterances=[replace(u, track=new_speaker(u.track, args.width, args.jaw))
                                        for u in train + validation + test])
    align_corpus(small, jobs=2, progress=False)

    base = load_model(args.model)
    started = time.perf_counter()
    adapted = copy.deepcopy(base).set_params(epochs=args.epochs, patience=8).fit(small, progress=False, warm_start=True)
    adapted_s = time.perf_counter() - started
    started = time.perf_counter()
    scratch = clone(base).set_params(epochs=args.epochs, patience=8).fit(small, progress=False)
    scratch_s = time.perf_counter() - started
    models = {f"{args.model} (unadapted)": base, "adapted on the new speaker": adapted, "from scratch": scratch}
    channels = [c for c in CHANNELS if c in base.channels]
    report = evaluate_models(small.split("test"), models, channels=channels, postprocessing="none")
    print(f"new speaker: stretch/smile x{args.width}, jawOpen +{args.jaw}; {len(train)} training, "
          f"{len(validation)} validation, {len(test)} test utterances")
    print(f"adaptation {adapted_s:.0f} s ({adapted.history_.epochs} epochs), from scratch {scratch_s:.0f} s "
          f"({scratch.history_.epochs} epochs)")
    print(f"{'model':28}" + "".join(f"{c + ' RMSE %':>24}{'r':>7}" for c in channels))
    for result in report.models:
        row = "".join(f"{result.scores[c]['rmse_percent']:>24.2f}{result.scores[c]['r']:>7.3f}" for c in channels)
        print(f"{result.label:28}{row}")


if __name__ == "__main__":
    main()
