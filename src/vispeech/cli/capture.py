"""``vispeech capture VIDEO``: a take (sound, face track, Live Link CSV, phones) from talking-face video."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import click

from vispeech.cli import language_option, main
from vispeech.errors import VispeechError
from vispeech.frontends.video import FACE_MODEL_VARIABLE


@main.command()
@click.argument("video", type=click.Path(path_type=Path))
@click.option("--text", "-t", default=None, help="The transcript: aligned with the sound into a phone TextGrid.")
@language_option("Language of the transcript (alignment: pocketsphinx for en, DTW on espeak-ng speech otherwise).")
@click.option(
    "--output",
    "-o",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="The take's folder (with --batch: the corpus folder).",
)
@click.option(
    "--face-model",
    type=click.Path(path_type=Path, dir_okay=False),
    envvar=FACE_MODEL_VARIABLE,
    show_envvar=True,
    help="MediaPipe's face_landmarker.task to track with [default: the one vispeech ships].",
)
@click.option(
    "--livelink",
    "livelink_csv",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="An iPhone Live Link Face recording: the app's CSV of this VIDEO; its blend shapes are kept "
    "(no tracking) and its timecodes lined up with the video's.",
)
@click.option(
    "--batch",
    is_flag=True,
    help="VIDEO is a folder of videos, each with its transcript beside it (<name>.txt): capture them all "
    "into one corpus folder, in parallel; a rerun skips the takes already there.",
)
@click.option(
    "--sync",
    is_flag=True,
    help="Move the face track by the estimated audio-video offset (always measured and reported, from how "
    "open the default audio model hears the jaw; takes of 3 s or more).",
)
@click.option("--smooth", is_flag=True, help="Filter tracker jitter (Savitzky-Golay, 0.2 s window).")
@click.option(
    "--jobs", "-j", default=None, type=click.IntRange(min=1), help="Videos at once with --batch [default: cores]."
)
def capture(
    video: Path,
    text: str | None,
    language: str,
    out_dir: Path,
    face_model: Path | None,
    livelink_csv: Path | None,
    batch: bool,
    sync: bool,
    smooth: bool,
    jobs: int | None,
) -> None:
    """Track the face in VIDEO with MediaPipe and write the take train and evaluate read.

    The take holds <name>.wav (16 kHz), <name>.face.csv (blend shapes, head pose and lip, jaw and
    eye landmarks per video frame; frames without a face left empty), <name>.csv (Live Link Face)
    and, with --text, <name>.TextGrid (docs/capture.md). Needs the capture extra.
    """
    from functools import partial

    from vispeech.corpus.capture import capture_corpus, capture_take, import_livelink_take
    from vispeech.pipeline import speech_openness

    if livelink_csv is not None:
        if batch or sync or smooth:
            raise VispeechError("--livelink imports one recording as it is: leave out --batch, --sync and --smooth")
        report = import_livelink_take(livelink_csv, video, out_dir, text=text, language=language)
        offset = report.timecode_offset
        assert offset is not None  # a Live Link import reports it (NaN without timecode)
        where = (
            "the video has no timecode: taken to start with the sound"
            if math.isnan(offset)
            else f"its first row at {offset:+.3f} s of the sound (timecodes)"
        )
        missing = f", {report.missing} not covered by the CSV (left empty)" if report.missing else ""
        click.echo(f"{report.frames} frames at {report.fps:g} fps{missing}; {where} -> {out_dir}/")
        return
    if batch:
        if text is not None:
            raise VispeechError("--batch reads each video's transcript from <name>.txt beside it: leave out --text")
        with click.progressbar(length=1, label="capturing", show_eta=True, show_pos=True, file=sys.stderr) as bar:
            summary = capture_corpus(
                video,
                out_dir,
                language=language,
                face_model=face_model,
                sync=sync,
                smooth=smooth,
                openness=partial(speech_openness, language=language),
                jobs=jobs,
                progress=_advance(bar),
            )
        click.echo(
            f"{summary.captured} captured, {summary.skipped} already there, {len(summary.failed)} failed -> {out_dir}/"
        )
        for name, reason in summary.failed:
            click.echo(f"  failed {name}: {reason}")
        if summary.failed:
            raise SystemExit(1)
        return
    with click.progressbar(length=1, label="tracking", show_eta=True, file=sys.stderr) as bar:
        report = capture_take(
            video,
            out_dir,
            text=text,
            language=language,
            face_model=face_model,
            sync=sync,
            smooth=smooth,
            openness=partial(speech_openness, language=language),
            progress=_advance(bar),
        )
    missing = f", {report.missing} without a face (left empty in {report.name}.face.csv)" if report.missing else ""
    phones = f", {report.phones} phones aligned" if text is not None else ""
    click.echo(
        f"{report.frames} frames at {report.fps:g} fps{missing}, {report.duration:.2f} s of sound{phones} -> {out_dir}/"
    )
    if math.isnan(report.offset):
        click.echo("audio-video offset: cannot be told (under 3 s, or the mouth does not move)")
    else:
        late = "late" if report.offset >= 0 else "early"
        done = "moved back in time with the sound" if report.synced else "--sync moves it"
        click.echo(f"audio-video offset: the picture is {abs(report.offset) * 1000:.0f} ms {late} ({done})")


def _advance(bar) -> Callable[[int, int], None]:
    """A ``progress(done, total)`` callback moving click's progress ``bar``."""

    def advance(done: int, total: int) -> None:
        bar.length = total
        bar.update(done - bar.pos)

    return advance
