"""What :meth:`~vispeech.models.contract.Estimator.fit` reads and shows: the corpus's training and
validation utterances (:class:`Splits` for plain lists, :func:`training_split`), the settings of
the run (:class:`FitRun`, with those a family fitted in one go refuses) and whether to show
progress (:func:`show_progress`)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from vispeech.errors import VispeechError


@dataclass(frozen=True)
class Splits:
    """Training data given as lists, read by :meth:`Estimator.fit` as a corpus with splits
    (``train`` to learn from, ``validation`` to stop early on)."""

    train: Sequence
    validation: Sequence = ()

    def split(self, name: str) -> list:
        """The utterances of split ``name`` (``train`` or ``validation``; ``test`` is empty)."""
        return list({"train": self.train, "validation": self.validation}.get(name, ()))


def training_split(corpus) -> tuple[list, list]:
    """``(train, validation)`` utterances of what :meth:`Estimator.fit` is given.

    A corpus with splits gives its ``train`` and ``validation`` splits; any other iterable
    of utterances trains on all of it with no validation. Raises :class:`VispeechError` on an
    empty training set or an utterance without phones.
    """
    if hasattr(corpus, "split"):
        train, validation = list(corpus.split("train")), list(corpus.split("validation"))
    elif isinstance(corpus, Iterable) and not isinstance(corpus, str | bytes):
        train, validation = list(corpus), []
    else:
        raise VispeechError("fit needs a corpus: an iterable of utterances with .phones and .track")
    if not train:
        raise VispeechError("cannot fit on an empty corpus")
    for utterance in train + validation:
        if getattr(utterance, "phones", None) is None:
            raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} has no phones: align the corpus first")
    return train, validation


def show_progress(progress: bool | None) -> bool:
    """What ``progress=None`` means: bars and lines when stderr is a terminal."""
    if progress is None:
        import sys

        return sys.stderr.isatty()
    return bool(progress)


@dataclass(frozen=True)
class FitRun:
    """The settings of one :meth:`~vispeech.models.contract.Estimator.fit`, never stored with the
    model (see its keywords)."""

    progress: bool | None = None
    checkpoint_dir: Path | None = None
    resume_from: Path | None = None
    num_threads: int | None = None
    warm_start: bool = False

    @classmethod
    def of(
        cls,
        progress: bool | None,
        checkpoint_dir: str | os.PathLike | None,
        resume_from: str | os.PathLike | None,
        num_threads: int | None,
        warm_start: bool,
    ) -> FitRun:
        """The settings from :meth:`~vispeech.models.contract.Estimator.fit`'s keywords."""
        if num_threads is not None and (
            isinstance(num_threads, bool) or not isinstance(num_threads, int) or num_threads < 1
        ):
            raise VispeechError(f"num_threads must be a whole number of 1 or more (or None), got {num_threads!r}")
        checkpoint, resume = (None if f is None else Path(f) for f in (checkpoint_dir, resume_from))
        return cls(progress, checkpoint, resume, num_threads, bool(warm_start))

    def in_one_go(self, family: str) -> None:
        """Raise :class:`VispeechError` when this run asks a family fitted in one go (no epochs to
        keep or go on from) for a ``checkpoint_dir``, ``resume_from`` or ``warm_start``."""
        given = {
            "checkpoint_dir": self.checkpoint_dir is not None,
            "resume_from": self.resume_from is not None,
            "warm_start": self.warm_start,
        }
        for setting in (name for name, on in given.items() if on):
            raise VispeechError(f"model {family} is fitted in one go: it takes no {setting}")
