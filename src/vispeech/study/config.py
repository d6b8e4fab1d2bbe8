"""A perceptual study described in TOML (``STUDY.toml``), and the sequence of trials each
participant sees.

The study shows composite clips (``vispeech stimuli render``: several models' faces side by
side, one sentence each, with its sound) cropped into one canvas per face, in the thesis's
two tasks:

- **rating**: every model of a clip at once, each rated 1-9 (labelled anchors);
- **pairwise**: two models of a clip, answered left / tie / right.

A participant's sequence (:func:`plan_trials`) follows the thesis: the items in a random
order, the faces at random positions; the first ``warmup`` items of each task copied to the
end, their first showing marked as warm-up and left out of the analysis; and two checks per
task: the **identical** check shows one model in two slots (a credible participant rates them
alike, or answers tie), the **mismatched** check plays the sound of another sentence (a
credible participant rates those faces below their own average, or prefers the face that
says the words).

A minimal ``STUDY.toml``::

    title = "Talking faces"
    intro = "You will see faces speak. Judge how they move their lips."
    consent = "I agree that my answers are stored without my name and used for research."

    [[questions]]
    id = "experience"
    text = "Experience with speech animation"
    choices = ["None", "Small", "Moderate", "Expert"]

    [[clips]]
    sentence = "s0"
    path = "clips/s0.mp4"
    models = ["recorded", "grid-tdnn", "baseline"]   # left to right in the clip

    [rating]
    question = "Please rate the realism of the animations (not of the face itself)."
    anchors = { 1 = "Not realistic at all", 5 = "Neither", 9 = "Completely realistic" }

    [pairwise]
    question = "Please indicate which animation you prefer."

Optional: ``[checks]`` (``identical``, ``mismatched``: true or false), ``warmup`` in each task
(default 3), ``pairs`` in ``[pairwise]``, ``models`` in ``[rating]``, ``thanks``, ``seed``, and
``[labels]`` (:class:`Labels`: the page's buttons and hints, for a study in another language).
"""

from __future__ import annotations

import itertools
import json
import os
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from vispeech.errors import VispeechError
from vispeech.files import read_text
from vispeech.study.answers import RATINGS

Task = Literal["rating", "pairwise"]
Check = Literal["", "identical", "mismatched"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Question(_Strict):
    """An intro question with fixed choices (the thesis asked experience, age and Swedish)."""

    id: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,39}$")
    text: str = Field(min_length=1)
    choices: list[str] = Field(min_length=2)


class Clip(_Strict):
    """A composite clip: the faces of ``models`` side by side (left to right) saying ``sentence``."""

    sentence: str = Field(min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.-]+$")
    path: Path
    text: str = ""
    """What is said (for the experimenter; participants only hear it)."""
    models: list[str] = Field(default_factory=list)

    @field_validator("models")
    @classmethod
    def _distinct(cls, models: list[str]) -> list[str]:
        if len(set(models)) != len(models):
            raise ValueError("a clip's models must be distinct")
        return models


class RatingTask(_Strict):
    """Rate every face of a clip from 1 to 9."""

    question: str = "Please rate the realism of the animations (not of the face itself)."
    anchors: dict[int, str] = Field(default_factory=lambda: {1: "Not realistic at all", 9: "Completely realistic"})
    models: list[str] | None = Field(default=None, min_length=2)
    """The models to show, two or more (default: every model of the clips)."""
    warmup: int = Field(default=3, ge=0)

    @field_validator("anchors", mode="before")
    @classmethod
    def _anchor_keys(cls, anchors: dict) -> dict:
        try:
            keys = {int(k): v for k, v in dict(anchors).items()}
        except (TypeError, ValueError):
            raise ValueError("anchors are keyed by ratings 1 to 9") from None
        if any(k not in RATINGS for k in keys):
            raise ValueError("anchors are keyed by ratings 1 to 9")
        return keys


class PairwiseTask(_Strict):
    """Choose the better of two faces, or a tie."""

    question: str = "Please indicate which animation you prefer."
    pairs: list[tuple[str, str]] | None = None
    """The pairs of models to compare (default: every pair of the clips' models)."""
    warmup: int = Field(default=3, ge=0)


class Checks(_Strict):
    """Which attention and credibility checks each task gets (one item each)."""

    identical: bool = True
    mismatched: bool = True


class Labels(_Strict):
    """The page's own words, for a study in another language (``[labels]``)."""

    start: str = "Start"
    play: str = "Play"
    play_again: str = "Play again"
    listen_first: str = "Play the clip to the end to answer."
    next: str = "Next"
    tie: str = "Equal"
    item: str = "Item {n} of {total}"
    not_saved: str = "Your answer was not saved, please answer again."


class Study(_Strict):
    """A perceptual study (see the module docstring); paths are relative to the TOML file."""

    title: str = Field(min_length=1)
    intro: str = ""
    consent: str = Field(min_length=1)
    thanks: str = "Thank you for taking part."
    questions: list[Question] = Field(default_factory=list)
    clips: list[Clip] = Field(min_length=1)
    rating: RatingTask | None = None
    pairwise: PairwiseTask | None = None
    checks: Checks = Checks()
    labels: Labels = Labels()
    seed: int = Field(default=0, ge=0, le=2**31 - 1)

    @model_validator(mode="after")
    def _consistent(self) -> Study:
        if self.rating is None and self.pairwise is None:
            raise ValueError("a study needs a [rating] or a [pairwise] task")
        if len({c.sentence for c in self.clips}) != len(self.clips):
            raise ValueError("each clip must have its own sentence")
        if len({q.id for q in self.questions}) != len(self.questions):
            raise ValueError("each question must have its own id")
        every = set().union(*(c.models for c in self.clips))
        for task, wanted in (
            ("rating", self.rating and self.rating.models),
            ("pairwise", self.pairwise and set(itertools.chain(*(self.pairwise.pairs or [])))),
        ):
            unknown = set(wanted or ()) - every
            if unknown:
                raise ValueError(f"[{task}] names models no clip shows: {', '.join(sorted(unknown))}")
        shown = self.rating and self.rating.models
        if self.rating and not any(
            len(set(c.models) & set(c.models if shown is None else shown)) >= 2 for c in self.clips
        ):
            raise ValueError("[rating] needs a clip that shows two of its models at least")
        if self.pairwise and self.pairwise.pairs and any(a == b for a, b in self.pairwise.pairs):
            raise ValueError("a pair compares two different models")
        if self.checks.mismatched and len(self.clips) < 2:
            raise ValueError("the mismatched-audio check needs two clips at least (or checks.mismatched = false)")
        return self


def read_study(path: str | os.PathLike) -> Study:
    """The study in the TOML file ``path``, its clip paths made absolute, each clip's models
    read from the key ``stimuli render`` wrote beside it (``clip.json``) where the TOML gives
    none. Raises :class:`VispeechError` with one line naming the problem."""
    path = Path(path)
    try:
        raw = tomllib.loads(read_text(path, "study"))
    except tomllib.TOMLDecodeError as exc:
        raise VispeechError(f"{path} is not valid TOML: {exc}") from None
    for clip in raw.get("clips", []) if isinstance(raw.get("clips"), list) else []:
        if isinstance(clip, dict) and isinstance(clip.get("path"), str):
            clip["path"] = str((path.parent / clip["path"]).resolve())
            if not clip.get("models"):
                clip["models"] = _models_from_key(Path(clip["path"]))
    try:
        study = Study.model_validate(raw)
    except ValidationError as exc:
        error = exc.errors()[0]
        where = ".".join(str(part) for part in error["loc"])
        message = error["msg"].removeprefix("Value error, ")  # pydantic's prefix for a validator's own words
        raise VispeechError(f"{path}: {where + ': ' if where else ''}{message}") from None
    for clip in study.clips:
        if not clip.path.is_file():
            raise VispeechError(f"{path}: clip {clip.sentence}: {clip.path} not found")
        with open(clip.path, "rb") as handle:
            if handle.read(12)[4:8] != b"ftyp":  # every MP4 file begins with its file-type box
                raise VispeechError(f"{path}: clip {clip.sentence}: {clip.path} is not an MP4 file")
        if len(clip.models) < 2:
            raise VispeechError(f"{path}: clip {clip.sentence} needs two models at least (models = [...])")
    if study.pairwise and not _pairs(study):
        raise VispeechError(f"{path}: no clip shows both models of a [pairwise] pair")
    return study


def _models_from_key(clip: Path) -> list[str]:
    """The models of a ``stimuli render`` clip, left to right: the stems of the animations its key
    names, or, where those are alike (``vispeech animate`` writes ``animation.json`` into each
    output folder), the names of their folders."""
    key = clip.with_suffix(".json")
    try:
        paths = [Path(name) for name in json.loads(key.read_text(encoding="utf-8"))["left_to_right"]]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    stems = [p.stem for p in paths]
    folders = [(key.parent / p).resolve().parent.name for p in paths]  # a relative name is the key's folder's
    return folders if len(set(stems)) < len(stems) and len(set(folders)) == len(folders) else stems


def _pairs(study: Study) -> list[tuple[Clip, str, str]]:
    """Every (clip, model, model) pairwise comparison the study asks for."""
    assert study.pairwise is not None
    out = []
    for clip in study.clips:
        wanted = study.pairwise.pairs or list(itertools.combinations(clip.models, 2))
        out += [(clip, a, b) for a, b in wanted if a in clip.models and b in clip.models]
    return out


@dataclass(frozen=True)
class Face:
    """One slot of a trial: column ``column`` of the clip of ``sentence``, showing ``model``."""

    sentence: str
    model: str
    column: int


@dataclass(frozen=True)
class Trial:
    """One item a participant answers: faces side by side with the sound of ``audio``."""

    task: Task
    faces: tuple[Face, ...]
    audio: str
    warmup: bool = False
    check: Check = ""

    @property
    def expected(self) -> str:
        """A check's credible answer: on a rating trial ``alike`` (identical) or ``lower``
        (mismatched, than the participant's own mean); on a pairwise trial ``tie`` (identical)
        or the side whose face says the words heard (mismatched); ``""`` for other trials."""
        if self.check == "identical":
            return "alike" if self.task == "rating" else "tie"
        if self.check == "mismatched":
            return "lower" if self.task == "rating" else ("left" if self.faces[0].sentence == self.audio else "right")
        return ""

    @property
    def sentence(self) -> str:
        """The sentence whose faces are shown (on a pairwise mismatched check: the one not heard)."""
        return next((f.sentence for f in self.faces if f.sentence != self.audio), self.audio)

    def to_json(self) -> dict:
        return {
            "task": self.task,
            "audio": self.audio,
            "warmup": self.warmup,
            "check": self.check,
            "faces": [[f.sentence, f.model, f.column] for f in self.faces],
        }

    @classmethod
    def from_json(cls, data: dict) -> Trial:
        return cls(
            task=data["task"],
            audio=data["audio"],
            warmup=data["warmup"],
            check=data["check"],
            faces=tuple(Face(s, m, int(c)) for s, m, c in data["faces"]),
        )


def plan_trials(study: Study, seed: int) -> list[Trial]:
    """The trials one participant sees, in order (the module docstring says how they are
    drawn); the same ``seed``, the same sequence."""
    rng = np.random.default_rng(seed)
    clips = {c.sentence: c for c in study.clips}
    trials: list[Trial] = []
    if study.rating is not None:
        wanted = study.rating.models
        items: list[list[Face]] = []
        for clip in study.clips:
            faces = [Face(clip.sentence, m, i) for i, m in enumerate(clip.models) if wanted is None or m in wanted]
            if len(faces) >= 2:
                items.append(faces)
        checks: list[Trial] = []
        if study.checks.identical:
            faces = items[int(rng.integers(len(items)))]
            twin = faces[0]
            checks.append(Trial("rating", tuple([twin, twin] + faces[2:]), twin.sentence, check="identical"))
        if study.checks.mismatched:
            faces = items[int(rng.integers(len(items)))]
            heard = _other_sentence(rng, clips, faces[0].sentence)
            checks.append(Trial("rating", tuple(faces), heard, check="mismatched"))
        trials += _block(rng, [Trial("rating", tuple(f), f[0].sentence) for f in items], checks, study.rating.warmup)
    if study.pairwise is not None:
        comparisons = _pairs(study)
        pairs = [
            Trial(
                "pairwise", (Face(c.sentence, a, c.models.index(a)), Face(c.sentence, b, c.models.index(b))), c.sentence
            )
            for c, a, b in comparisons
        ]
        checks = []
        if study.checks.identical:
            clip, a, _ = comparisons[int(rng.integers(len(comparisons)))]
            face = Face(clip.sentence, a, clip.models.index(a))
            checks.append(Trial("pairwise", (face, face), clip.sentence, check="identical"))
        if study.checks.mismatched:
            clip, a, _ = comparisons[int(rng.integers(len(comparisons)))]
            other = clips[_other_sentence(rng, clips, clip.sentence)]
            if a in other.models:
                pair = (Face(clip.sentence, a, clip.models.index(a)), Face(other.sentence, a, other.models.index(a)))
                checks.append(Trial("pairwise", pair, clip.sentence, check="mismatched"))
        trials += _block(rng, pairs, checks, study.pairwise.warmup)
    return trials


def _other_sentence(rng: np.random.Generator, clips: dict[str, Clip], sentence: str) -> str:
    others = sorted(s for s in clips if s != sentence)
    return others[int(rng.integers(len(others)))]


def _shuffled_faces(rng: np.random.Generator, trial: Trial) -> Trial:
    return replace(trial, faces=tuple(trial.faces[i] for i in rng.permutation(len(trial.faces))))


def _block(rng: np.random.Generator, items: list[Trial], checks: list[Trial], warmup: int) -> list[Trial]:
    """One task's trials: the items shuffled (faces too), the checks placed at random after the
    warm-up, and the first ``warmup`` items shown again at the end (their first showing marked)."""
    items = [_shuffled_faces(rng, items[i]) for i in rng.permutation(len(items))]
    warmup = min(warmup, len(items))
    first = [replace(t, warmup=True) for t in items[:warmup]]
    rest = items[warmup:]
    for check in checks:
        rest.insert(int(rng.integers(len(rest) + 1)), _shuffled_faces(rng, check))
    return first + rest + [_shuffled_faces(rng, t) for t in items[:warmup]]
