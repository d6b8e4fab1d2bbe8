"""``vispeech corpus info DIR``: what a corpus folder holds."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main
from vispeech.cli._corpus_input import cache_option, corpus_language_option


@main.group("corpus")
def corpus_group() -> None:
    """Inspect recorded corpora (GRID folders, folders of Live Link Face takes)."""


@corpus_group.command("info")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.option("--no-phones", is_flag=True, help="Skip phone coverage (and the alignment it may need).")
@corpus_language_option
@cache_option
@click.option("--strict", is_flag=True, help="Fail on the first bad utterance instead of skipping it.")
def info_command(directory: Path, no_phones: bool, language: str, cache: Path | None, strict: bool) -> None:
    """Print utterances, duration, frame rate, channels, splits and phone coverage of DIRECTORY."""
    import warnings
    from dataclasses import replace

    from vispeech.corpus import SPLITS, CorpusWarning, align_corpus, read_corpus
    from vispeech.corpus.corpus import frame_rates_text
    from vispeech.phonetics.inventory import get_inventory, is_silence

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)  # skipped utterances are listed below
        corpus = read_corpus(directory, language=language, strict=strict, cache=cache)
    echo = click.echo
    echo(f"corpus: {corpus.name} ({corpus.language})")
    echo(f"utterances: {len(corpus)}" + (f" ({len(corpus.problems)} skipped)" if corpus.problems else ""))
    for problem in corpus.problems:
        echo(f"  {problem}")
    echo(f"duration: {corpus.duration:.1f} s ({corpus.duration / 60:.1f} min)")
    echo(f"fps: {frame_rates_text(corpus.frame_rates)}")
    echo(f"channels ({len(corpus.channels)}): {', '.join(corpus.channels)}")
    echo("splits: " + ", ".join(f"{name} {len(corpus.split(name))}" for name in SPLITS))
    if no_phones or not len(corpus):
        return

    if any(u.phones is None for u in corpus):
        n_problems = len(corpus.problems)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CorpusWarning)
            align_corpus(corpus, progress=True, strict=strict)
        for problem in corpus.problems[n_problems:]:
            echo(f"  {problem}")
    aligned = [u for u in corpus if u.phones is not None]
    coverage = replace(corpus, utterances=aligned).phone_coverage()
    inventory = get_inventory(corpus.language).symbols
    echo(f"phone coverage ({len(aligned)} utterances, {sum(coverage.values())} phones):")
    for symbol, count in sorted(coverage.items(), key=lambda item: (-item[1], item[0])):
        echo(f"  {symbol}\t{count}")
    missing = [s for s in inventory if s not in coverage and not is_silence(s)]
    echo(f"missing inventory phones: {', '.join(missing) if missing else 'none'}")
