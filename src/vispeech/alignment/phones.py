"""The time-aligned phone sequence: phones with start/end seconds, words, stress, language."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, overload

import numpy as np

from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import SILENCE, is_silence


@dataclass(frozen=True)
class Word:
    """A word with its start and end in seconds."""

    text: str
    start: float
    end: float


@dataclass(frozen=True)
class Phone:
    """One phone: inventory symbol, start and end in seconds, word index, stress.

    ``symbol`` never carries a stress digit (ARPAbet ``AA1`` is ``symbol="AA", stress=1``);
    ``word`` indexes :attr:`PhoneSequence.words` (``None`` for silences between words).
    """

    symbol: str
    start: float
    end: float
    word: int | None = None
    stress: int = 0

    @property
    def duration(self) -> float:
        return self.end - self.start

    @property
    def is_silence(self) -> bool:
        return is_silence(self.symbol)


@dataclass
class PhoneSequence:
    """Phones of one utterance in time order, with their words and language (``"sv"``, ``"en"``)."""

    phones: list[Phone]
    language: str
    words: list[Word] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.phones)

    def __iter__(self):
        return iter(self.phones)

    @property
    def duration(self) -> float:
        """End time of the last phone in seconds (0 for an empty sequence)."""
        return self.phones[-1].end if self.phones else 0.0

    @property
    def symbols(self) -> list[str]:
        return [p.symbol for p in self.phones]

    @property
    def starts(self) -> np.ndarray:
        return np.array([p.start for p in self.phones], dtype=float)

    @property
    def ends(self) -> np.ndarray:
        return np.array([p.end for p in self.phones], dtype=float)

    def validate(self) -> PhoneSequence:
        """Raise :class:`VispeechError` unless phones are non-empty, ordered and non-overlapping, with
        stress 0, 1 or 2 and words that exist."""
        if not self.phones:
            raise VispeechError("phone sequence is empty")
        previous_end = 0.0
        for i, p in enumerate(self.phones):
            if not p.symbol:
                raise VispeechError(f"phone {i} has an empty symbol")
            if not (math.isfinite(p.start) and math.isfinite(p.end)) or p.end <= p.start:
                raise VispeechError(f"phone {i} ({p.symbol}) has start {p.start} >= end {p.end}")
            if p.start < previous_end - TIME_TOLERANCE:
                raise VispeechError(f"phone {i} ({p.symbol}) starts at {p.start:.3f} s, before the previous phone ends")
            if p.stress not in (0, 1, 2):
                raise VispeechError(f"phone {i} ({p.symbol}) has stress {p.stress}; stress is 0, 1 or 2")
            if p.word is not None and not 0 <= p.word < len(self.words):
                raise VispeechError(f"phone {i} ({p.symbol}) refers to missing word {p.word}")
            previous_end = p.end
        return self

    def with_gaps_filled(self) -> PhoneSequence:
        """A copy where time before, between and after phones is covered by silence phones."""
        filled: list[Phone] = []
        t = 0.0
        for p in self.phones:
            if p.start > t + TIME_TOLERANCE:
                filled.append(Phone(SILENCE, t, p.start))
            filled.append(p)
            t = p.end
        return replace(self, phones=filled)

    def n_frames(self, fps: float) -> int:
        """Number of frames at ``fps`` that cover ``[0, duration)``: frame k sits at time k/fps."""
        return n_frames_for(self.duration, fps)

    def frame_indices(self, fps: float, n_frames: int | None = None) -> np.ndarray:
        """For each frame, the index of the phone covering its time (-1 where none does).

        Frame k sits at ``k / fps`` seconds; a phone covers ``[start, end)``.
        """
        n = self.n_frames(fps) if n_frames is None else n_frames
        times = np.arange(n) / fps
        idx = np.searchsorted(self.ends, times, side="right")
        idx = np.minimum(idx, len(self.phones) - 1) if self.phones else np.full(n, -1)
        if self.phones:
            inside = (self.starts[idx] <= times + TIME_TOLERANCE) & (times < self.ends[idx])
            idx = np.where(inside, idx, -1)
        return idx.astype(int)

    def frame_labels(self, fps: float, n_frames: int | None = None) -> list[str]:
        """Per-frame phone symbols at ``fps`` (``sil`` where no phone covers a frame)."""
        return [self.phones[i].symbol if i >= 0 else SILENCE for i in self.frame_indices(fps, n_frames)]

    def shifted(self, seconds: float) -> PhoneSequence:
        """A copy with every time moved by ``seconds``."""
        return replace(
            self,
            phones=[replace(p, start=p.start + seconds, end=p.end + seconds) for p in self.phones],
            words=[replace(w, start=w.start + seconds, end=w.end + seconds) for w in self.words],
        )

    def scaled(self, factor: float) -> PhoneSequence:
        """A copy with every time multiplied by ``factor`` (the same speech ``1 / factor`` times as fast)."""
        return replace(
            self,
            phones=[replace(p, start=p.start * factor, end=p.end * factor) for p in self.phones],
            words=[replace(w, start=w.start * factor, end=w.end * factor) for w in self.words],
        )

    def to_dict(self) -> dict:
        """JSON-ready form: ``{"language", "words": [...], "phones": [...]}``."""
        return {
            "language": self.language,
            "words": [{"text": w.text, "start": w.start, "end": w.end} for w in self.words],
            "phones": [
                {"symbol": p.symbol, "start": p.start, "end": p.end, "word": p.word, "stress": p.stress}
                for p in self.phones
            ],
        }

    @classmethod
    def from_dict(cls, data: dict) -> PhoneSequence:
        """Inverse of :meth:`to_dict`; raises :class:`VispeechError` on a malformed dict, a value
        of the wrong type included (a word index or stress that is not a whole number, a symbol
        or word that is not text)."""
        try:
            words = [Word(_typed(w["text"], str), float(w["start"]), float(w["end"])) for w in data.get("words", [])]
            phones = [
                Phone(
                    _typed(p["symbol"], str),
                    float(p["start"]),
                    float(p["end"]),
                    None if p.get("word") is None else _typed(p["word"], int),
                    _typed(p.get("stress", 0), int),
                )
                for p in data["phones"]
            ]
            return cls(phones=phones, language=_typed(data.get("language", "en"), str), words=words)
        except (AttributeError, KeyError, TypeError, ValueError) as exc:  # AttributeError: a list, no dict
            raise VispeechError(f"malformed phone sequence: {exc}") from None


def _typed(value: object, kind: type) -> Any:
    """``value`` if it is a ``kind`` (a bool is no number), else a :class:`TypeError` naming it."""
    if not isinstance(value, kind) or isinstance(value, bool):
        raise TypeError(f"{value!r} is not {'a whole number' if kind is int else 'text'}")
    return value


TIME_TOLERANCE = 1e-6
"""Seconds: two times closer than this are the same time (phone boundaries, frame times)."""


@overload
def first_frame(seconds: float, fps: float, after: bool = True) -> int: ...


@overload
def first_frame(seconds: np.ndarray, fps: float, after: bool = True) -> np.ndarray: ...  # a 0-d array gives an int


def first_frame(seconds: float | np.ndarray, fps: float, after: bool = True) -> int | np.ndarray:
    """The first frame k whose time ``k / fps`` is at or after ``seconds`` (``after``), or the
    last one at or before it; within :data:`TIME_TOLERANCE` counts as at. An int for a number,
    an array of them for an array."""
    position = np.asarray(seconds, dtype=float) * fps
    slack = TIME_TOLERANCE * fps
    frame = np.ceil(position - slack) if after else np.floor(position + slack)
    return int(frame) if frame.ndim == 0 else frame.astype(int)


def n_frames_for(duration: float, fps: float) -> int:
    """Frames at ``fps`` needed to cover ``duration`` seconds (at least 1)."""
    if fps <= 0:
        raise VispeechError(f"fps must be positive, got {fps}")
    return max(1, first_frame(duration, fps))
