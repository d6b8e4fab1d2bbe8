"""``vispeech sweep look-ahead|window``: error against one hyper-parameter, one trained model per value."""

from __future__ import annotations

import json
from pathlib import Path

import click

from vispeech.cli import main, quiet_option
from vispeech.cli._corpus_input import cache_option, corpus_language_option, corpus_option, read_aligned_corpus
from vispeech.errors import VispeechError


@main.command("sweep")
@click.argument("what", type=click.Choice(["look-ahead", "window"]))
@corpus_option
@click.option("--values", required=True, help="Comma-separated whole numbers of frames, e.g. 0,1,2,4,8,15.")
@click.option(
    "--model",
    "-m",
    "family",
    default=None,
    help="Family to train [default: tdnn-lowlatency for look-ahead, sliding-window-taylor for window].",
)
@click.option(
    "--param",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="Another hyper-parameter for every model (JSON value), e.g. epochs=30 or hidden=[500,500].",
)
@click.option(
    "--output",
    "-o",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder for sweep.csv, sweep.json and the figure (PNG and SVG).",
)
@corpus_language_option
@cache_option
@quiet_option
def sweep_command(
    what: str,
    corpus_dir: Path,
    values: str,
    family: str | None,
    params: tuple[str, ...],
    out_dir: Path,
    language: str,
    cache: Path | None,
    quiet: bool,
) -> None:
    """Train a model per value of the look-ahead (Beskow 2004, Fig. 4) or the input window (Taylor et
    al. 2017, Fig. 11) on the corpus's train split and plot its test-split jawOpen error against it."""
    from vispeech.evaluation.sweep import SWEEPS, plot_sweep, sweep
    from vispeech.files import atomic_output_dir, check_output_dir

    outputs = ("sweep.csv", "sweep.json", "sweep.png", "sweep.svg")
    check_output_dir(out_dir, replaces=outputs)  # before the training, not after it

    default_family, parameter = SWEEPS[what]
    family = family or default_family
    try:
        numbers = [int(v) for v in values.split(",") if v.strip()]
    except ValueError:
        raise VispeechError(f"--values must be whole numbers separated by commas, got {values!r}") from None
    if not numbers or min(numbers) < 0:
        raise VispeechError("--values needs one whole number of frames or more, none negative")
    options = {}
    for text in params:
        key, sep, value = text.partition("=")
        if not sep:
            raise VispeechError(f"--param takes KEY=VALUE, got {text!r}")
        try:
            options[key] = json.loads(value)
        except json.JSONDecodeError:
            options[key] = value
    corpus = read_aligned_corpus(corpus_dir, language, cache, progress=not quiet)
    points = sweep(corpus, family, parameter, numbers, options, progress=click.echo, fit_progress=not quiet)
    with atomic_output_dir(out_dir, replaces=outputs) as staging:
        rows = ["value,rmse_percent,r,epochs,seconds"] + [
            f"{p.value},{p.rmse_percent:.6g},{p.r:.6g},{p.epochs},{p.seconds:.1f}" for p in points
        ]
        (staging / "sweep.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
        (staging / "sweep.json").write_text(
            json.dumps(
                {
                    "family": family,
                    "parameter": parameter,
                    "corpus": corpus.name,
                    "params": options,
                    "points": [vars(p) for p in points],
                },
                indent=2,
            ),
            encoding="utf-8",
        )
        plot_sweep(points, parameter, family, staging / "sweep")
    click.echo(f"{len(points)} models -> {out_dir}/sweep.png")
