"""Reading a corpus folder of either layout: GRID or a folder of Live Link Face takes."""

from __future__ import annotations

import os
from pathlib import Path

from vispeech.corpus.corpus import Corpus
from vispeech.corpus.grid import read_grid
from vispeech.corpus.takes import read_takes
from vispeech.errors import VispeechError


def read_corpus(
    directory: str | os.PathLike,
    *,
    language: str = "sv",
    strict: bool = False,
    cache: str | os.PathLike | None = None,
) -> Corpus:
    """Read ``directory`` as a GRID folder (``sentences.tsv`` + ``utterances/``) or else as takes.

    ``language`` applies to takes (GRID is English); ``strict`` and ``cache`` are passed to
    :func:`~vispeech.corpus.grid.read_grid` or :func:`~vispeech.corpus.takes.read_takes`.
    """
    root = Path(directory)
    if not root.is_dir():
        raise VispeechError(f"corpus folder not found: {root}")
    if (root / "sentences.tsv").is_file() and (root / "utterances").is_dir():
        return read_grid(root, strict=strict, cache=cache)
    return read_takes(root, language=language, strict=strict, cache=cache)
