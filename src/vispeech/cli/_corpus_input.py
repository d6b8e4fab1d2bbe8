"""What the commands that read a corpus share: the options that name it and reading it."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import language_option
from vispeech.corpus.corpus import Corpus
from vispeech.errors import VispeechError

corpus_option = click.option(
    "--corpus",
    "corpus_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Corpus folder (GRID layout or a folder of Live Link takes).",
)
corpus_language_option = language_option(
    "Language of a folder of takes (its transcripts and TextGrid symbols): sv or en; a GRID folder is en.",
)
cache_option = click.option(
    "--cache",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Cache folder for alignments [default: ~/.cache/vispeech/<name>-<hash>, or $VISPEECH_CACHE].",
)


def open_corpus(directory: Path, language: str, cache: Path | None = None) -> Corpus:
    """Read a corpus folder; skipped utterances are summed up on stderr, none usable is an error."""
    import warnings

    from vispeech.corpus import CorpusWarning, read_corpus
    from vispeech.phonetics.inventory import get_inventory

    get_inventory(language)  # an unknown language, refused before anything is read or aligned
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)  # listed in corpus.problems, summed up below
        corpus = read_corpus(directory, language=language, cache=cache)
    if not len(corpus):
        raise VispeechError(
            f"corpus {directory} has no usable utterances" + (f" ({corpus.problems[0]})" if corpus.problems else "")
        )
    if corpus.problems:
        click.echo(f"{len(corpus.problems)} utterances skipped (first: {corpus.problems[0]})", err=True)
    return corpus


def read_aligned_corpus(directory: Path, language: str, cache: Path | None, progress: bool) -> Corpus:
    """:func:`open_corpus`, aligned (cached); utterances that cannot be aligned are left out."""
    import warnings
    from dataclasses import replace

    from vispeech.corpus import CorpusWarning, align_corpus

    corpus = open_corpus(directory, language, cache)
    skipped = len(corpus.problems)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        align_corpus(corpus, progress=progress)
    if len(corpus.problems) > skipped:
        click.echo(
            f"{len(corpus.problems) - skipped} utterances not aligned (first: {corpus.problems[skipped]})", err=True
        )
    aligned = [u for u in corpus if u.phones is not None]
    if not aligned:
        raise VispeechError(f"no utterance of corpus {corpus.name} could be aligned")
    return replace(corpus, utterances=aligned)
