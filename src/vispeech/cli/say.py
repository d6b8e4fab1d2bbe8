"""``vispeech say`` and ``vispeech animate-phones``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from vispeech.cli import language_option, life_options, main, postprocessing_option, scale_option
from vispeech.errors import VispeechError
from vispeech.frontends.espeak import check_voice
from vispeech.frontends.sentiment import sentiment
from vispeech.limits import check_fps, check_text
from vispeech.models.registry import RUNNABLE
from vispeech.motion.life import check_layers, with_life
from vispeech.motion.rigging.calibration import load_scale
from vispeech.pipeline import (
    DEFAULT_FPS,
    DEFAULT_MODEL,
    DEFAULT_SCALE,
    GREETINGS,
    Utterance,
    animate,
    check_outputs,
    speak,
    write_outputs,
)

_model_option = click.option(
    "--model",
    "-m",
    default=DEFAULT_MODEL,
    show_default=True,
    help=f"One of {', '.join(RUNNABLE)} (see `vispeech models`), or a saved model folder.",
)
_fps_option = click.option("--fps", default=DEFAULT_FPS, show_default=True, type=float, help="Frames per second.")


@main.command()
@click.argument("text", required=False)
@language_option("Language of the text: sv, en or any other `vispeech languages` lists.")
@click.option("--output", "-o", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder.")
@_model_option
@_fps_option
@click.option("--rate", default=1.0, show_default=True, type=float, help="Speaking-rate factor (1.0 = normal).")
@postprocessing_option()
@click.option(
    "--text-file",
    type=click.Path(path_type=Path),
    default=None,
    help="Speak the text of this file (UTF-8; at most 10,000 characters) instead of TEXT.",
)
@scale_option(DEFAULT_SCALE)
@click.option(
    "--voice",
    default=None,
    help="The avatar's voice: f1-f5 female, m1-m8 male, ... "
    "(`vispeech languages --voices`) [default: the language's own voice].",
)
@life_options
def say(
    text: str | None,
    language: str,
    out_dir: Path,
    model: str,
    fps: float,
    rate: float,
    postprocessing: str,
    text_file: Path | None,
    scale: str,
    voice: str | None,
    life: str,
    seed: int,
) -> None:
    """Speak TEXT and write speech.wav, phones.TextGrid, animation.csv/.json and preview.html.

    Without TEXT (or --text-file) a greeting in the chosen language is spoken. Markdown markup,
    links and emoji are not spoken.
    """
    check_fps(fps, "--fps")
    if text_file is not None:
        if text is not None:
            raise VispeechError("give TEXT or --text-file, not both")
        from vispeech.files import read_text

        text = read_text(text_file, "text file")
    if text is None:
        text = GREETINGS.get(language)
        if text is None:
            raise VispeechError(f"vispeech greets in sv and en only; give TEXT to speak {language!r}")
    check_text(text)
    check_outputs(out_dir)
    load_scale(scale)  # a bad scale, voice or layer is refused before any work
    check_voice(voice)
    layers = check_layers(life)
    utterance = speak(text, language, model=model, rate=rate, fps=fps, postprocessing=postprocessing, voice=voice)
    phones = utterance.phones
    assert utterance.track is not None and phones is not None  # speak() animates espeak-ng's phones
    track = with_life(utterance.track, phones, layers, seed, mood=sentiment(text, language))
    utterance = replace(utterance, track=track)
    paths = write_outputs(utterance, out_dir, scale=scale)
    click.echo(f"{track.n_frames} frames at {fps:g} fps, {phones.duration:.2f} s -> {out_dir}/")
    for path in paths:
        click.echo(f"  {path.name}")


@main.command("animate-phones")
@click.argument("alignment", type=click.Path(path_type=Path))
@click.option("--output", "-o", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder.")
@language_option("Phone set of the symbols: sv, en or ipa [default: guessed from the symbols].", default=None)
@_model_option
@_fps_option
@postprocessing_option()
@scale_option(DEFAULT_SCALE)
@life_options
def animate_phones(
    alignment: Path,
    out_dir: Path,
    language: str | None,
    model: str,
    fps: float,
    postprocessing: str,
    scale: str,
    life: str,
    seed: int,
) -> None:
    """Animate a phone alignment (TextGrid, HTK .lab, GRID .align or JSON).

    Writes OUTPUT/animation.csv (Live Link Face, first row at time 0 of the alignment) and
    OUTPUT/animation.json.
    """
    from vispeech.alignment.formats import read_alignment

    check_fps(fps, "--fps")
    check_outputs(out_dir, inputs=[alignment])
    load_scale(scale)
    layers = check_layers(life)
    try:
        phones = read_alignment(alignment, language)
    except VispeechError as exc:
        if alignment.suffix.lower() == ".align" and "unknown phone symbol" in str(exc):
            raise VispeechError(
                f"{exc}; a GRID .align file times words, not phones: animate its audio with "
                '`vispeech animate AUDIO --text "THE WORDS"`'
            ) from None
        raise
    track = with_life(animate(phones, model, fps, postprocessing), phones, layers, seed)
    write_outputs(Utterance(phones=phones, track=track), out_dir, scale=scale)
    click.echo(f"{track.n_frames} frames at {fps:g} fps -> {out_dir}/animation.csv, animation.json")
