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
@click.option(
    "--sync",
    is_flag=True,
    help="Also tell how far each take's picture is out of step with its sound (from its lip landmarks "
    "and the jaw the default audio model hears; takes of 3 s or more) and list those off by more than a frame.",
)
def info_command(directory: Path, no_phones: bool, language: str, cache: Path | None, strict: bool, sync: bool) -> None:
    """Print utterances, duration, frame rate, channels, splits and phone coverage of DIRECTORY."""
    import warnings
    from dataclasses import replace

    from vispeech.corpus import SPLITS, CorpusWarning, align_corpus, read_corpus
    from vispeech.corpus.corpus import frame_rates_text
    from vispeech.phonetics.inventory import get_inventory, is_silence

    get_inventory(language)  # an unknown language, refused before anything is read or aligned
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
    if sync and len(corpus):
        _print_sync(corpus, language)
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


SYNC_LISTED = 20
"""How many of the takes most out of step ``corpus info --sync`` names."""


def _print_sync(corpus, language: str) -> None:
    """Each take's A/V offset (:func:`vispeech.corpus.av_sync.utterance_offset`), summed up."""
    from functools import partial

    import numpy as np
    from tqdm.auto import tqdm

    from vispeech.corpus.av_sync import MIN_OPENNESS_SECONDS, utterance_offset
    from vispeech.models.registry import load_model
    from vispeech.pipeline import default_audio_model, speech_openness

    name = default_audio_model(language)
    openness = partial(speech_openness, language=language, model=load_model(name))
    offsets = np.array([utterance_offset(u, openness) for u in tqdm(corpus, desc="syncing", unit="take")])
    measured = np.isfinite(offsets)
    echo = click.echo
    echo(
        f"A/V sync (+: the picture late; from the lip landmarks against the jaw {name} hears): "
        f"{measured.sum()} of {len(corpus)} takes measured"
        + ("" if measured.all() else f" (the others lack lip landmarks or last under {MIN_OPENNESS_SECONDS:g} s)")
    )
    if not measured.any():
        return
    frame = np.array([1 / u.track.fps for u in corpus])
    off = measured & (np.abs(np.nan_to_num(offsets)) > frame)
    echo(
        f"  median {np.median(offsets[measured]) * 1000:+.0f} ms, {off.sum()} off by more than a frame"
        + (": re-sync or leave them out before training" if off.any() else "")
    )
    order = sorted(np.flatnonzero(off), key=lambda i: -abs(offsets[i]))
    for i in order[:SYNC_LISTED]:
        echo(f"  {corpus.utterances[i].id}\t{offsets[i] * 1000:+.0f} ms")
    if len(order) > SYNC_LISTED:
        echo(f"  ... and {len(order) - SYNC_LISTED} more")
