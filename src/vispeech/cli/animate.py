"""``vispeech animate AUDIO``: recorded speech to animation."""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import click

from vispeech.cli import language_option, life_options, main, postprocessing_option, scale_option
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.sentiment import sentiment
from vispeech.limits import check_fps
from vispeech.models.registry import RUNNABLE
from vispeech.motion.life import check_layers, with_life
from vispeech.motion.rigging.calibration import load_scale
from vispeech.pipeline import (
    DEFAULT_AUDIO_MODEL,
    DEFAULT_FPS,
    DEFAULT_MODEL,
    DEFAULT_SCALE,
    WHISPER_AUDIO_MODEL,
    WHISPER_ENSEMBLE_MODEL,
    check_outputs,
    listen,
    write_outputs,
)
from vispeech.utterance import Utterance


@main.command()
@click.argument("audio", type=click.Path(path_type=Path))
@click.option("--text", "-t", default=None, help="The transcript, aligned with the audio: its phones drive the model.")
@click.option(
    "--transcribe", is_flag=True, help="Recognise the transcript with Whisper (the whisper extra), then as --text."
)
@click.option(
    "--whisper-model",
    type=click.Path(path_type=Path),
    default=None,
    help="A CTranslate2 Whisper folder used for this run instead of the installed models: "
    "by --transcribe and by audio networks on Whisper features ($VISPEECH_WHISPER_MODEL).",
)
@click.option("--force", is_flag=True, help="Animate an English transcript that does not fit the audio all the same.")
@language_option("Language of the recording: any `vispeech languages` lists (the transcript's).")
@click.option("--output", "-o", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder.")
@click.option(
    "--model",
    "-m",
    default=None,
    help=f"One of {', '.join(RUNNABLE)} (see `vispeech models`), or a saved model folder "
    f"[default: {WHISPER_ENSEMBLE_MODEL} with the whisper extra, else {DEFAULT_AUDIO_MODEL}; with --text or "
    f"--transcribe {DEFAULT_MODEL}, blended with {WHISPER_AUDIO_MODEL} for English with the whisper extra].",
)
@click.option("--fps", default=DEFAULT_FPS, show_default=True, type=float, help="Frames per second.")
@postprocessing_option()
@scale_option(DEFAULT_SCALE)
@life_options
def animate(
    audio: Path,
    text: str | None,
    transcribe: bool,
    whisper_model: Path | None,
    force: bool,
    language: str,
    out_dir: Path,
    model: str | None,
    fps: float,
    postprocessing: str,
    scale: str,
    life: str,
    seed: int,
) -> None:
    """Animate the speech in AUDIO (WAV, FLAC, MP3, OGG; at most 10 minutes).

    Writes speech.wav, animation.csv/.json, preview.html and, with --text or --transcribe,
    phones.TextGrid. Without either an audio model animates the sound; with --text the
    transcript is aligned with the audio and the model animates its phones (an audio model
    the sound, blended with them); --transcribe has
    Whisper hear the transcript first (English by Whisper tiny.en, other languages by Whisper
    base; docs/audio.md). An English transcript that does not fit the audio is refused
    (--force: animated all the same).
    """
    if text is not None and transcribe:
        raise VispeechError("give --text or --transcribe, not both")
    check_fps(fps, "--fps")
    check_outputs(out_dir, inputs=[audio])
    load_scale(scale)
    layers = check_layers(life)
    with _whisper_folder(whisper_model):
        clip = AudioClip.read(audio)
        if transcribe:
            from vispeech.frontends.transcribe import transcribe as heard

            text = heard(clip, language)
        utterance = _listened(clip, text, language, force, model=model, fps=fps, postprocessing=postprocessing)
    assert utterance.track is not None  # listen() animates the clip
    track = with_life(utterance.track, utterance.phones, layers, seed, mood=sentiment(utterance.text or "", language))
    utterance = replace(utterance, track=track)
    paths = write_outputs(utterance, out_dir, title=utterance.text or audio.name, scale=scale)
    if transcribe:
        click.echo(f"transcript: {utterance.text}")
    click.echo(f"{track.n_frames} frames at {fps:g} fps, {clip.duration:.2f} s -> {out_dir}/")
    for path in paths:
        click.echo(f"  {path.name}")


def _listened(clip: AudioClip, text: str | None, language: str, force: bool, **options) -> Utterance:
    """:func:`listen`; a transcript that does not fit the audio is refused with a pointer to --force."""
    from vispeech.frontends.align import TranscriptMismatch

    try:
        return listen(clip, text, language, force=force, **options)
    except TranscriptMismatch as exc:
        raise VispeechError(f"{exc} (--force: animate it all the same)") from None


@contextmanager
def _whisper_folder(folder: Path | None):
    """``$VISPEECH_WHISPER_MODEL`` set to ``folder`` (checked first) while the block runs: every
    named Whisper model of the run, the transcriber's and an audio network's features, then
    loads from it. Nothing changes without a folder."""
    if folder is None:
        yield
        return
    from vispeech.frontends.whisper import MODEL_ENV, model_folder

    checked = str(model_folder(str(folder)))
    before = os.environ.get(MODEL_ENV)
    os.environ[MODEL_ENV] = checked
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(MODEL_ENV, None)
        else:
            os.environ[MODEL_ENV] = before
