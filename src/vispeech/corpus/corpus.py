"""The corpus type: utterances with audio, words, phones and a face track, and its splits."""

from __future__ import annotations

import hashlib
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

from vispeech.corpus.cache import CorpusCache
from vispeech.errors import VispeechError
from vispeech.motion.track import Track
from vispeech.utterance import Utterance  # noqa: F401  (the corpus type of utterances)

SPLITS: dict[str, tuple[float, float]] = {
    "train": (0.0, 0.8),
    "validation": (0.8, 0.9),
    "test": (0.9, 1.0),
}
"""Each split's share of the unit interval that :func:`split_of` maps utterance ids into."""

ALL = "all"
"""What :meth:`Corpus.split` takes for every utterance: the whole of a corpus kept for
evaluation only, whose splits mean nothing."""

MAX_DURATION_MISMATCH = 0.5
"""Seconds by which a face track and its audio may differ in length before readers reject them."""


class CorpusWarning(UserWarning):
    """An utterance was skipped while reading a corpus; the message names it and says why."""


def split_of(utterance_id: str) -> str:
    """The split (``"train"``, ``"validation"`` or ``"test"``) an utterance id belongs to.

    The id's SHA-256 is read as a number in [0, 1) and placed by :data:`SPLITS` (80/10/10):
    the same id always lands in the same split, whatever else the corpus holds.
    """
    position = int.from_bytes(hashlib.sha256(utterance_id.encode("utf-8")).digest()[:8], "big") / 2**64
    for name, (low, high) in SPLITS.items():
        if low <= position < high:
            return name
    raise AssertionError("SPLITS must cover [0, 1)")  # pragma: no cover


@dataclass
class Corpus:
    """A named list of utterances sharing one set of track channels.

    Each utterance's track keeps its own frame rate (``utterance.track.fps``): clips filmed at
    25 and at 30 fps may sit in one corpus, and whatever works per utterance uses the
    utterance's rate. ``fps`` is the rate of the corpus's tracks, for a corpus of several
    (:attr:`frame_rates`) the one most of them have (:func:`common_frame_rate`).
    ``problems`` lists the utterances the reader skipped, one line each; ``cache`` is where
    derived data (alignments) is kept.
    """

    name: str
    utterances: list[Utterance]
    fps: float
    channels: tuple[str, ...]
    language: str = "en"
    root: Path | None = None
    problems: list[str] = field(default_factory=list)
    cache: CorpusCache | None = None

    def __len__(self) -> int:
        return len(self.utterances)

    def __iter__(self) -> Iterator[Utterance]:
        return iter(self.utterances)

    def __getitem__(self, key: int | str) -> Utterance:
        """The utterance at a position or with an id."""
        if isinstance(key, str):
            for utterance in self.utterances:
                if utterance.id == key:
                    return utterance
            raise VispeechError(f"corpus {self.name} has no utterance {key!r}")
        return self.utterances[key]

    def __repr__(self) -> str:
        rates = frame_rates_text(self.frame_rates)
        return f"Corpus({self.name!r}, {len(self)} utterances, {rates} fps, {len(self.channels)} channels)"

    @property
    def ids(self) -> list[str]:
        return [u.id for u in self.utterances]

    @property
    def frame_rates(self) -> tuple[float, ...]:
        """The frame rates of the utterances' tracks, each once, lowest first (``(fps,)`` without utterances)."""
        return tuple(sorted({_rate(recorded_track(u).fps) for u in self.utterances})) or (self.fps,)

    @property
    def duration(self) -> float:
        """Total audio duration in seconds."""
        total = 0.0
        for u in self.utterances:
            assert u.duration is not None, f"utterance {u.id} has no duration"  # every corpus reader sets it
            total += u.duration
        return float(total)

    def split(self, name: str) -> Corpus:
        """The sub-corpus of split ``name`` (``train``, ``validation``, ``test``; see :func:`split_of`),
        or of every utterance for :data:`ALL`."""
        if name not in (*SPLITS, ALL):
            raise VispeechError(f"unknown split {name!r} (use {', '.join(SPLITS)} or {ALL})")
        kept = [u for u in self.utterances if name == ALL or split_of(u.id) == name]
        return replace(self, name=f"{self.name}:{name}", utterances=kept, problems=[])

    def phone_coverage(self) -> Counter:
        """How many times each phone symbol occurs, over all utterances (silences included).

        Raises :class:`VispeechError` if an utterance has no phones yet (align the corpus first
        with :func:`vispeech.corpus.align_corpus`).
        """
        missing = [u.id for u in self.utterances if u.phones is None]
        if missing:
            raise VispeechError(
                f"{len(missing)} utterances have no phones (first: {missing[0]}); align the corpus first"
            )
        return Counter(p.symbol for u in self.utterances if u.phones is not None for p in u.phones)


def recorded_track(utterance: Utterance) -> Track:
    """The face track of a corpus utterance (every corpus reader sets one)."""
    assert utterance.track is not None, f"utterance {utterance.id} has no face track"
    return utterance.track


def _rate(fps: float) -> float:
    """A frame rate rounded to 0.001 fps, so that 29.97 fps measured on two clips is one rate."""
    return round(float(fps), 3)


def common_frame_rate(tracks: Iterable[Track], default: float) -> float:
    """The frame rate most of ``tracks`` have (the lowest of equally common ones); ``default`` for none."""
    counts = Counter(_rate(track.fps) for track in tracks)
    return min(counts, key=lambda rate: (-counts[rate], rate)) if counts else default


def frame_rates_text(rates: Iterable[float]) -> str:
    """Frame rates for a line of text: ``"25"``, ``"25 and 30"``, ``"24, 25 and 30"``."""
    names = [f"{rate:g}" for rate in rates]
    return ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else "".join(names)


def report_problem(problems: list[str], message: str, strict: bool) -> None:
    """Record a skipped utterance: raise :class:`VispeechError` if ``strict``, else warn and list it."""
    if strict:
        raise VispeechError(message)
    warnings.warn(message, CorpusWarning, stacklevel=3)
    problems.append(message)


def check_durations(track: Track, audio_duration: float) -> None:
    """Raise :class:`VispeechError` if a face track and its audio differ by more than
    :data:`MAX_DURATION_MISMATCH` seconds."""
    if abs(track.duration - audio_duration) > MAX_DURATION_MISMATCH:
        raise VispeechError(f"face track lasts {track.duration:.2f} s but the audio {audio_duration:.2f} s")
