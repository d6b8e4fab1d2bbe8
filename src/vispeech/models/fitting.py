"""What :meth:`~vispeech.models.contract.Estimator.fit` reads and shows: the corpus's training and
validation utterances (:class:`Splits` for plain lists, :func:`training_split`), whether to
show progress (:func:`show_progress`) and the run settings a family fitted in one go refuses
(:func:`fitted_in_one_go`)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

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


def fitted_in_one_go(family: str, checkpoint_dir, resume_from, warm_start: bool) -> None:
    """Raise :class:`VispeechError` when a family fitted in one go (no epochs to keep or go on
    from) is given a ``checkpoint_dir``, ``resume_from`` or ``warm_start``."""
    given = {
        "checkpoint_dir": checkpoint_dir is not None,
        "resume_from": resume_from is not None,
        "warm_start": warm_start,
    }
    for setting in (name for name, on in given.items() if on):
        raise VispeechError(f"model {family} is fitted in one go: it takes no {setting}")
