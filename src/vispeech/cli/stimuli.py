"""``vispeech stimuli``: material for perceptual tests."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main
from vispeech.errors import VispeechError


@main.group("stimuli")
def stimuli_group() -> None:
    """Make stimuli for perceptual tests (docs/evaluation.md)."""


@stimuli_group.command("vocode")
@click.argument("audio", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The degraded speech (.wav).",
)
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

    if output.suffix.lower() != ".wav":
        raise VispeechError(f"{output}: the degraded speech is written as .wav")
    clip = AudioClip.read(audio)
    degraded = noise_vocode(clip.samples, clip.sample_rate, bands=bands, low=low, high=high, seed=seed)
    with atomic_output_file(output) as tmp:
        tmp.write_bytes(wav_bytes(degraded, clip.sample_rate))
    edges = ", ".join(f"{e:.0f}" for e in band_edges(bands, low, high))
    click.echo(f"{clip.duration:.2f} s, {bands} bands (edges {edges} Hz) -> {output}")


@stimuli_group.command("render")
@click.argument("animations", nargs=-1, required=True, type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--audio",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="The sound of the clip (e.g. speech.wav, or one vocoded by `stimuli vocode`).",
)
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The clip (.mp4); beside it OUTPUT.json says which animation is where.",
)
@click.option(
    "--shuffle",
    "seed",
    type=click.IntRange(min=0),
    default=None,
    help="Place the animations in a random order from this seed (a trial's; default: as given).",
)
@click.option(
    "--head",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="Render on this GLB head (ARKit morph targets) [default: the shipped ICT-FaceKit head].",
)
@click.option("--head-as-is", is_flag=True, help="Use --head untouched (no tongue targets or paint added).")
@click.option("--face-2d", "face_2d", is_flag=True, help="Render on the 2D face instead of a 3D head.")
def render(
    animations: tuple[Path, ...],
    audio: Path | None,
    output: Path,
    seed: int | None,
    head: Path | None,
    head_as_is: bool,
    face_2d: bool,
) -> None:
    """Render ANIMATIONS (Live Link CSV or vispeech JSON, the same frame rate) on a GLB head (the
    shipped one unless --head names another) or the 2D face, side by side, with AUDIO, to an MP4
    (H.264 + AAC) for a perceptual test. Needs Chromium (/usr/bin/chromium, or VISPEECH_CHROMIUM),
    Playwright and Pillow (the test extra); the head is drawn on the CPU, 7-11 heads a second on 2
    cores."""
    import json

    import numpy as np

    from vispeech.evaluation.stimuli import render_faces
    from vispeech.files import atomic_output_file
    from vispeech.frontends.audio import AudioClip
    from vispeech.motion.formats.registry import read_track
    from vispeech.motion.rigging.head import DEFAULT_HEAD

    if output.suffix.lower() != ".mp4":
        raise VispeechError("the clip is an .mp4 file")
    if head_as_is and head is None:
        raise VispeechError("--head-as-is needs --head")
    if face_2d and head is not None:
        raise VispeechError("give --head or --face-2d, not both")
    shown = None if face_2d else head or DEFAULT_HEAD
    tracks = [read_track(path) for path in animations]
    clip = AudioClip.read(audio) if audio is not None else None
    order = list(range(len(tracks))) if seed is None else np.random.default_rng(seed).permutation(len(tracks)).tolist()
    render_faces(
        tracks,
        output,
        audio=None if clip is None else clip.samples,
        sample_rate=None if clip is None else clip.sample_rate,
        order=order,
        head=shown,
        prepare_head=head is not None and not head_as_is,  # the shipped head is shipped prepared
    )
    key = output.with_suffix(".json")
    with atomic_output_file(key) as tmp:
        tmp.write_text(
            json.dumps(
                {
                    "clip": output.name,
                    "seed": seed,
                    "audio": None if audio is None else str(audio.resolve()),
                    "head": None if shown is None else str(shown.resolve()),
                    "left_to_right": [str(animations[i].resolve()) for i in order],
                },
                indent=2,
            )
            + "\n",
            encoding="utf-8",
        )
    frames = max(t.n_frames for t in tracks)
    click.echo(
        f"{frames} frames at {tracks[0].fps:g} fps on {shown.name if shown else 'the 2D face'}, left to right: "
        f"{', '.join(animations[i].name for i in order)} -> {output} (key: {key.name})"
    )
