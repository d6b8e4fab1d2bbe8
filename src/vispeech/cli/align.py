"""``vispeech align AUDIO TEXT -o OUT.TextGrid``: forced alignment of English speech."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import lang_option, main


@main.command("align")
@click.argument("audio", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("text")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="File to write: .TextGrid (words and phones tiers), .json, .lab or .align.")
@lang_option("Language of the speech (only en).", name="language")
def align_command(audio: Path, text: str, output: Path, language: str) -> None:
    """Align TEXT with the speech in AUDIO (WAV, FLAC) and write its words and phones."""
    from vispeech.alignment.formats import write_alignment
    from vispeech.frontends.align import align
    from vispeech.frontends.audio import read_audio

    samples, sample_rate = read_audio(audio)
    phones = align(samples, sample_rate, text, language)
    write_alignment(phones, output)
    click.echo(f"{output}: {len(phones.words)} words, {len(phones)} phones, {phones.duration:.2f} s")
