"""``vispeech align AUDIO TEXT -o OUT.TextGrid``: forced alignment of speech with its transcript."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import language_option, main


@main.command("align")
@click.argument("audio", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("text")
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="File to write: .TextGrid (words and phones tiers), .json, .lab or .align.",
)
@language_option(
    "Language of the speech: en (pocketsphinx) or any other `vispeech languages` lists (DTW against espeak-ng).",
)
@click.option(
    "--method",
    type=click.Choice(["pocketsphinx", "dtw"]),
    help="pocketsphinx (English only) or DTW against espeak-ng's speech of TEXT "
    "(default: pocketsphinx for en, dtw for sv).",
)
def align_command(audio: Path, text: str, output: Path, language: str, method: str | None) -> None:
    """Align TEXT with the speech in AUDIO (WAV, FLAC) and write its words and phones."""
    from vispeech.alignment.formats import write_alignment
    from vispeech.frontends.align import align
    from vispeech.frontends.audio import AudioClip

    clip = AudioClip.read(audio)
    phones = align(clip.samples, clip.sample_rate, text, language, method=method)
    write_alignment(phones, output)
    click.echo(f"{output}: {len(phones.words)} words, {len(phones)} phones, {phones.duration:.2f} s")
