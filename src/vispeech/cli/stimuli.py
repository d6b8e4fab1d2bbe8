"""``vispeech stimuli``: material for perceptual tests."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main


@main.group("stimuli")
def stimuli_group() -> None:
    """Make stimuli for perceptual tests (docs/evaluation.md)."""


@stimuli_group.command("vocode")
@click.argument("audio", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--output", "-o", "output", required=True, type=click.Path(path_type=Path, dir_okay=False),
              help="The degraded speech (.wav).")
@click.option("--bands", default=3, show_default=True, type=click.IntRange(1, 32), help="Vocoder bands.")
@click.option("--low", default=100.0, show_default=True, type=float, help="Lowest band edge (Hz).")
@click.option("--high", default=5000.0, show_default=True, type=float, help="Highest band edge (Hz).")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed of the noise.")
def vocode(audio: Path, output: Path, bands: int, low: float, high: float, seed: int) -> None:
    """Degrade AUDIO with a noise-excited vocoder (Shannon et al. 1995; 3 bands, 100-5000 Hz, as
    Beskow 2004 tested intelligibility): the rhythm and rough spectrum of speech without its fine
    structure, so that the face has to help."""
    from vispeech.evaluation.stimuli import band_edges, noise_vocode
    from vispeech.files import atomic_output_file
    from vispeech.frontends.audio import AudioClip, wav_bytes

    clip = AudioClip.read(audio)
    degraded = noise_vocode(clip.samples, clip.sample_rate, bands=bands, low=low, high=high, seed=seed)
    with atomic_output_file(output) as tmp:
        tmp.write_bytes(wav_bytes(degraded, clip.sample_rate))
    edges = ", ".join(f"{e:.0f}" for e in band_edges(bands, low, high))
    click.echo(f"{clip.duration:.2f} s, {bands} bands (edges {edges} Hz) -> {output}")
