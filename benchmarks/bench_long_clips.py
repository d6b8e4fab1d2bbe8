"""Audio models on long recordings: the same speech alone and inside a long clip.

    python benchmarks/bench_long_clips.py [--models grid-audio-cnn ...] [--group 8]
                                          [--split validation] [--level-db -20] [--seed 0]

The audio models learned from 3-s utterances that begin and end in silence; users send
minutes of continuous speech, and a live session runs for as long as the page is open. This
builds long clips from a split of grid_s1 (the validation split by default: no model trained
on it), shuffled with ``--seed``, ``--group`` utterances a clip, each clip opened by a random
0.3–2 s of its last utterance's audio (so that no window of the models lines up with an
utterance), and scores every utterance's stretch of the long clip's prediction against its
tracked jaw. Three layouts, each beside the same utterances predicted one by one:

- ``pauses kept``: the utterances whole, their silences included;
- ``continuous``: each cut to its scored span plus 0.25 s either side, so that one sentence
  runs into the next as in natural speech (the cut utterance is also what is predicted alone);
- ``level change``: pauses kept, twice as many utterances a clip, the second half
  ``--level-db`` quieter (a microphone's gain turned down, another speaker further away);
  only that half is scored, alone at the same level.

Prints jawOpen r (raw output, no post-processing, mean over utterances, on each utterance's
scored frames as ``vispeech evaluate`` takes them) per model and layout.
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vispeech.corpus import CorpusWarning, read_grid
from vispeech.evaluation.report import scored_frames, target_track
from vispeech.frontends.audio import AudioClip
from vispeech.models.contract import Estimator
from vispeech.models.registry import load_model
from vispeech.utterance import Utterance

GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"
RATE = 16_000
MARGIN = 0.25
"""Seconds kept either side of an utterance's scored span in the continuous layout."""


def split_utterances(corpus: Path, split: str) -> list[Utterance]:
    """The utterances of a split of the GRID corpus at ``corpus`` (exits without it)."""
    if not corpus.is_dir():
        raise SystemExit(f"needs the GRID corpus at {corpus}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        return list(read_grid(corpus).split(split))


def jaw(model: Estimator, samples: np.ndarray, fps: float) -> np.ndarray:
    """The raw jawOpen ``model`` predicts for ``samples`` (16 kHz) at ``fps``."""
    track = model.predict_with_closures(AudioClip.from_array(samples, RATE), fps)[0]
    return track.select(["jawOpen"]).values[:, 0]


def pieces(utterances: Sequence[Utterance], fps: float, cut: bool) -> list[tuple[np.ndarray, slice]]:
    """Each utterance's audio (whole, or ``cut`` to its scored span ± :data:`MARGIN`), a whole
    number of frames long, and the frames of its track that audio covers."""
    out = []
    for utterance in utterances:
        samples, sample_rate = utterance.load_audio()
        if sample_rate != RATE:
            raise SystemExit(f"{utterance.id}: expected {RATE} Hz audio, got {sample_rate}")
        n = utterance.track.n_frames
        whole = np.zeros(round(n / fps * RATE), dtype=np.float32)
        whole[: min(len(whole), len(samples))] = samples[: len(whole)]
        frames = slice(0, n)
        if cut:
            spoken = np.flatnonzero(scored_frames(utterance))
            frames = slice(max(0, spoken[0] - round(MARGIN * fps)), min(n, spoken[-1] + 1 + round(MARGIN * fps)))
        out.append((whole[round(frames.start / fps * RATE) : round(frames.stop / fps * RATE)], frames))
    return out


def r_of(prediction: np.ndarray, utterance: Utterance, frames: slice) -> float:
    """jawOpen r of ``prediction`` (the frames ``frames`` of ``utterance``) on its scored frames."""
    scored = scored_frames(utterance)[frames]
    truth = target_track(utterance, ["jawOpen"]).values[frames, 0]
    return float(np.corrcoef(prediction[: len(truth)][scored], truth[scored])[0, 1])


def layout_scores(model: Estimator, utterances: Sequence[Utterance], group: int, rng: np.random.Generator,
                  cut: bool = False, level: float = 1.0) -> tuple[float, float]:
    """Mean jawOpen r of the scored utterances predicted alone and inside long clips of ``group``
    (the second half of each clip scaled by ``level`` and scored alone when ``level`` != 1)."""
    alone, inside = [], []
    fps = utterances[0].track.fps
    for first in range(0, len(utterances) - group + 1, group):
        members = utterances[first : first + group]
        audio = pieces(members, fps, cut)
        gains = [1.0] * group if level == 1.0 else [1.0] * (group // 2) + [level] * (group - group // 2)
        last = audio[-1][0]
        lead = last[len(last) - min(len(last), round(rng.uniform(0.3, 2.0) * RATE)) :]
        clip = np.concatenate([lead, *(samples * gain for (samples, _), gain in zip(audio, gains))])
        prediction = jaw(model, clip, fps)
        offset = len(lead)  # samples before the next utterance
        for utterance, (samples, frames), gain in zip(members, audio, gains):
            at = round(offset / RATE * fps)
            if level == 1.0 or gain != 1.0:
                inside.append(r_of(prediction[at : at + frames.stop - frames.start], utterance, frames))
                alone.append(r_of(jaw(model, samples * gain, fps), utterance, frames))
            offset += len(samples)
    return float(np.mean(alone)), float(np.mean(inside))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["grid-audio-cnn", "grid-audio-encdec"])
    parser.add_argument("--group", type=int, default=8, help="utterances a long clip (twice that for the level change)")
    parser.add_argument("--split", default="validation", choices=("validation", "test", "train"))
    parser.add_argument("--level-db", type=float, default=-20.0, help="the level change (dB)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--corpus", type=Path, default=GRID)
    args = parser.parse_args()
    utterances = split_utterances(args.corpus, args.split)
    order = np.random.default_rng(args.seed).permutation(len(utterances))
    utterances = [utterances[i] for i in order]
    layouts = (("pauses kept", args.group, False, 1.0), ("continuous", args.group, True, 1.0),
               (f"level change {args.level_db:+g} dB", 2 * args.group, False, 10 ** (args.level_db / 20)))
    print(f"{len(utterances)} grid_s1 {args.split} utterances in long clips; jawOpen r (raw), alone → inside")
    print(f"{'model':32}" + "".join(f"{name:>30}" for name, *_ in layouts))
    for name in args.models:
        model = load_model(name)
        cells = []
        for _, group, cut, level in layouts:
            alone, inside = layout_scores(model, utterances, group, np.random.default_rng(args.seed), cut, level)
            cells.append(f"{alone:.3f} → {inside:.3f} ({inside - alone:+.3f})")
        print(f"{name:32}" + "".join(f"{cell:>30}" for cell in cells), flush=True)


if __name__ == "__main__":
    main()
