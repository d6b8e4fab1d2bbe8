"""A ready study from a recorded corpus: the recording itself and each model's animation of
the same sentences, rendered side by side with the sentence's sound, and the ``study.toml``
that runs them (``vispeech study prepare``).

The thesis compared the captured motion (ground truth), its network and a rule baseline on
the same sentences; here ``"recorded"`` is the corpus's own track and every other entry a
model's prediction of the same utterance, post-processed as users get it. The recording is
cut to the channels the models animate (a face is judged on what every face could show), and
every track is shown in ARKit's scale, as a head gets it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from vispeech.corpus import Corpus
from vispeech.errors import VispeechError
from vispeech.evaluation.report import predict_on_frames, target_track
from vispeech.evaluation.stimuli import noise_vocode, render_faces
from vispeech.files import atomic_output_dir
from vispeech.models.contract import Estimator
from vispeech.motion.rigging.calibration import load_scale

RECORDED = "recorded"
"""The name of the corpus's own track among a study's models."""

STUDY_FILE = "study.toml"

INTRO = (
    "You will see faces saying short sentences, side by side, and hear what they say. "
    "Judge how well the lips, jaw and tongue move with the speech, not how the face looks. "
    "Please use headphones, and play each clip to its end before you answer."
)
CONSENT = (
    "I agree to take part. My answers are stored without my name and used for research only; I may stop at any time."
)
QUESTIONS = (
    (
        "experience",
        "Experience in speech animation or visual speech technology",
        ["None", "Small", "Moderate", "Expert"],
    ),
    ("age", "Age", ["Under 20", "20-29", "30-39", "40-49", "50-59", "60 or over"]),
    ("language", "Proficiency in the language spoken", ["None", "Small", "Moderate", "Good", "Native speaker"]),
)
"""The intro questions of the thesis (Table 4.3), the age in coarser steps."""


def prepare_study(
    corpus: Corpus,
    models: Mapping[str, Estimator | None],
    out_dir: str | os.PathLike,
    *,
    sentences: int = 10,
    seed: int = 0,
    vocode: bool = False,
    head: str | os.PathLike | None = None,
    title: str = "Talking faces",
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write a study folder: ``clips/<utterance>.mp4`` (the faces of ``models`` left to right,
    with the utterance's sound, through the noise vocoder when ``vocode``; on the 2D face, or on
    the 3D ``head`` (a GLB, prepared as ``serve --avatar`` prepares it)), a key beside each,
    and ``study.toml`` with both tasks (rating every face, every pair) and the thesis's intro
    questions. ``models`` maps a name to a model, or to None for the recording itself
    (:data:`RECORDED`). ``sentences`` utterances of ``corpus`` are drawn at random (``seed``).
    Written atomically; returns the path of ``study.toml``."""
    if len(models) < 2:
        raise VispeechError("a study compares two models at least (the recording counts as one: recorded)")
    if not len(corpus):
        raise VispeechError(f"corpus {corpus.name} has no utterances")
    channels = _shown_channels(corpus, models)
    rng = np.random.default_rng(seed)
    chosen = sorted(rng.choice(len(corpus), size=min(sentences, len(corpus)), replace=False).tolist())
    arkit = load_scale("arkit")
    assert arkit is not None  # only the "tracker" scale is None
    clips = []
    with atomic_output_dir(out_dir, replaces=(STUDY_FILE, "clips")) as staging:
        (staging / "clips").mkdir()
        for n, index in enumerate(chosen, start=1):
            utterance = corpus[index]
            tracks = [
                arkit.apply(target_track(utterance, channels) if model is None else predict_on_frames(model, utterance))
                for model in models.values()
            ]
            samples, rate = utterance.load_audio()
            if vocode:
                samples = noise_vocode(samples, rate)
            render_faces(tracks, staging / "clips" / f"{utterance.id}.mp4", audio=samples, sample_rate=rate, head=head)
            key = {
                "clip": f"{utterance.id}.mp4",
                "sentence": utterance.id,
                "text": utterance.text,
                "vocoded": vocode,
                "head": None if head is None else str(head),
                "left_to_right": list(models),
            }
            (staging / "clips" / f"{utterance.id}.json").write_text(json.dumps(key, indent=2) + "\n", encoding="utf-8")
            clips.append((utterance.id, utterance.text))
            if progress is not None:
                progress(f"[{n}/{len(chosen)}] {utterance.id}: {utterance.text}")
        (staging / STUDY_FILE).write_text(_study_toml(title, clips, list(models), seed), encoding="utf-8")
    return Path(out_dir) / STUDY_FILE


def _shown_channels(corpus: Corpus, models: Mapping[str, Estimator | None]) -> list[str]:
    """The recorded channels every track is cut to: those some model animates (or, with the
    recording alone against nothing, all)."""
    animated = {c for model in models.values() if model is not None for c in model.channels}
    shown = [c for c in corpus.channels if c in animated]
    if not shown:
        raise VispeechError(f"the models animate none of corpus {corpus.name}'s channels")
    return shown


def _toml(value: object) -> str:
    """A TOML value: strings as basic strings (JSON's escapes are TOML's), lists of them."""
    return json.dumps(value, ensure_ascii=False)


def _study_toml(title: str, clips: list[tuple[str, str]], models: list[str], seed: int) -> str:
    lines = [
        f"# Made by `vispeech study prepare`; edit the texts, then `vispeech study serve {STUDY_FILE}`.",
        f"title = {_toml(title)}",
        f"intro = {_toml(INTRO)}",
        f"consent = {_toml(CONSENT)}",
        f"seed = {seed}",
        "",
    ]
    for qid, text, choices in QUESTIONS:
        lines += ["[[questions]]", f"id = {_toml(qid)}", f"text = {_toml(text)}", f"choices = {_toml(choices)}", ""]
    for sentence, text in clips:
        lines += [
            "[[clips]]",
            f"sentence = {_toml(sentence)}",
            f"text = {_toml(text)}",
            f"path = {_toml(f'clips/{sentence}.mp4')}",
            f"models = {_toml(models)}",
            "",
        ]
    lines += [
        "[rating]",
        'question = "Please rate how natural the mouth movements are (not the face itself)."',
        'anchors = { 1 = "Not natural at all", 5 = "Neither", 9 = "Completely natural" }',
        "warmup = 3",
        "",
        "[pairwise]",
        'question = "Which face speaks more naturally?"',
        "warmup = 3",
        "",
    ]
    if len(clips) < 2:
        lines += ["[checks]", "mismatched = false  # it plays another clip's sound: one clip has none to play", ""]
    return "\n".join(lines)
