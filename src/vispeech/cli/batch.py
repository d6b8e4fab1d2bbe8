"""``vispeech batch JOB -o OUT``: many lines at once, in parallel, resumable."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import click

from vispeech.cli import language_option, life_options, main, postprocessing_option, scale_option
from vispeech.errors import VispeechError
from vispeech.models.registry import RUNNABLE
from vispeech.pipeline import DEFAULT_FPS, DEFAULT_OUTPUTS, DEFAULT_SCALE, OUTPUT_FILES


@main.command()
@click.argument("job", type=click.Path(path_type=Path))
@click.option(
    "--output",
    "-o",
    "out_dir",
    required=True,
    type=click.Path(path_type=Path),
    help="Output folder: one folder per line, and index.jsonl.",
)
@language_option("Language of lines that do not say: any `vispeech languages` lists.")
@click.option(
    "--model",
    "-m",
    default=None,
    help=f"Model of lines that do not say: one of {', '.join(RUNNABLE)}, or a saved model folder "
    "[default: grid-tdnn; for audio without text grid-audio-whisper-ensemble with the whisper extra, "
    "else grid-audio-encdec].",
)
@click.option(
    "--fps", default=DEFAULT_FPS, show_default=True, type=float, help="Frames per second of lines that do not say."
)
@click.option(
    "--formats",
    default=",".join(DEFAULT_OUTPUTS),
    show_default=True,
    help=f"Files of lines that do not say, comma-separated: {', '.join(OUTPUT_FILES)}.",
)
@postprocessing_option("How lines that do not say are post-processed")
@click.option(
    "--jobs", "-j", type=click.IntRange(min=1), default=None, help="Worker processes [default: one per core]."
)
@click.option(
    "--backend",
    type=click.Choice(["local", "ray"]),
    default="local",
    show_default=True,
    help="Where lines run: a local pool of processes, or Ray (the ray extra).",
)
@click.option(
    "--address",
    default=None,
    help="With --backend ray: the cluster to join (HEAD:6379 or auto) [default: a local Ray instance].",
)
@click.option("--force", is_flag=True, help="Redo lines whose outputs are up to date.")
@click.option(
    "--trust-transcripts",
    is_flag=True,
    help="Animate every English audio line on its transcript without checking that it fits the audio "
    "(the check is about half of such a line's time; a wrong transcript then gives wrong lips).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
@scale_option(DEFAULT_SCALE)
@click.option(
    "--voice",
    default=None,
    help="The voice of text lines that do not say: f1-f5 female, m1-m8 male, ... (`vispeech languages --voices`).",
)
@life_options
def batch(
    job: Path,
    out_dir: Path,
    language: str,
    model: str | None,
    fps: float,
    formats: str,
    postprocessing: str,
    jobs: int | None,
    backend: str,
    address: str | None,
    force: bool,
    trust_transcripts: bool,
    quiet: bool,
    scale: str,
    voice: str | None,
    life: str,
    seed: int,
) -> None:
    """Animate every line of JOB into OUTPUT/<id>/.

    JOB is a folder of inputs (.txt texts, audio with an optional same-name .txt transcript,
    alignments) or a manifest: CSV with a header, or JSONL, with the fields id, text, language,
    audio, alignment, model, fps, rate, formats, postprocessing, voice (docs/batch.md). A rerun redoes
    only the lines whose input or settings changed. A failed line is reported at the end and
    never stops the others; the exit code is then 1.
    """
    from vispeech.batch import JobDefaults, read_job, run_batch
    from vispeech.limits import check_fps
    from vispeech.motion.life import check_layers
    from vispeech.motion.rigging.calibration import load_scale
    from vispeech.pipeline import check_formats

    load_scale(scale)
    defaults = JobDefaults(
        language=language,
        model=model,
        fps=check_fps(fps, "--fps"),
        formats=check_formats(f for f in formats.split(",") if f.strip()),
        postprocessing=postprocessing,
        scale=scale,
        voice=voice,
        life=check_layers(life),
        seed=seed,
        check_transcripts=not trust_transcripts,
    )
    lines = read_job(job, defaults)
    if address is not None and backend != "ray":
        raise VispeechError("--address is for --backend ray")
    if backend == "ray":
        import ray  # noqa: F401 (an error naming the extra before any work)
    workers = jobs or os.cpu_count() or 1
    where = f" on Ray ({address or 'a local instance'})" if backend == "ray" else ""
    click.echo(f"{len(lines)} lines from {job}, {workers} worker{'s' * (workers > 1)}{where} -> {out_dir}/", err=True)
    with click.progressbar(
        length=len(lines),
        label="animating",
        show_eta=True,
        show_pos=True,
        file=sys.stderr,
        hidden=quiet,
        item_show_func=lambda result: result and result.id,
    ) as bar:
        report = run_batch(
            lines,
            out_dir,
            workers=workers,
            backend=backend,
            address=address,
            force=force,
            progress=lambda result: bar.update(1, result),
        )
    rate = len(lines) / report.seconds if report.seconds > 0 else 0.0
    click.echo(
        f"{report.count('written')} written, {report.count('unchanged')} unchanged, "
        f"{report.count('failed')} failed in {report.seconds:.1f} s ({rate:.1f} lines/s) -> {report.index}"
    )
    for result in report.failed:
        click.echo(f"failed: line {result.number} ({result.id}): {result.error}", err=True)
    if report.failed:
        sys.exit(1)
