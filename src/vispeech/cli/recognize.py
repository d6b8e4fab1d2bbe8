"""``vispeech recognize AUDIO -o OUT.TextGrid``: English phones from speech alone."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main


@main.command("recognize")
@click.argument("audio", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="File to write: .TextGrid, .json, .lab or .align.",
)
def recognize_command(audio: Path, output: Path) -> None:
    """Recognise the English phones spoken in AUDIO (WAV, FLAC) without a transcript and write
    them. Far less accurate than ``vispeech align``: use that when the words are known."""
    from vispeech.alignment.formats import write_alignment
    from vispeech.frontends.audio import AudioClip
    from vispeech.frontends.recognize import recognize_phones

    clip = AudioClip.read(audio)
    phones = recognize_phones(clip.samples, clip.sample_rate)
    write_alignment(phones, output)
    spoken = sum(not p.is_silence for p in phones)
    click.echo(f"{output}: {spoken} phones (and {len(phones) - spoken} silences), {phones.duration:.2f} s")
