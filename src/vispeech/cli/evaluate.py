"""``vispeech evaluate``: objective scores of models against a corpus's recorded tracks."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main, postprocessing_option, quiet_option
from vispeech.cli._corpus_input import cache_option, corpus_language_option, corpus_option, read_aligned_corpus
from vispeech.corpus.corpus import ALL, SPLITS, recorded_track
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, check_output_dir, check_output_file


@main.command("evaluate")
@corpus_option
@click.option(
    "--split",
    default="test",
    show_default=True,
    type=click.Choice([*SPLITS, ALL]),
    help=f"Utterances to score: a split, or {ALL} for the whole corpus (one kept for evaluation "
    "only, such as another speaker's).",
)
@click.option(
    "--model",
    "-m",
    "model_specs",
    multiple=True,
    required=True,
    help="Model name (baseline, beskow-rules, cohen-massaro, ohman, ...) or a trained model "
    "folder; repeat to compare; `shipped` for every shipped trained model.",
)
@click.option(
    "--channels",
    default=None,
    help="Comma-separated channels to score [default: the mouth/jaw channels model and corpus share]; "
    "jawOpen is always scored when both have it.",
)
@postprocessing_option("How predictions are post-processed before scoring")
@click.option(
    "--transcript",
    is_flag=True,
    help="Give audio models the utterances' aligned phones too, as `animate --text` does "
    "(their frames blended with the phone model's, the lips closed on the phones' bilabials).",
)
@click.option(
    "--sync",
    is_flag=True,
    help="Re-sync recordings whose picture and sound are out of step (web video): move every model's "
    "predictions by the lag of each utterance of 6 s or more, where the default phone model's jawOpen "
    "agrees best with the recording's (within 0.3 s); the lags are summed up in the header.",
)
@click.option(
    "--markdown",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also write the tables to this Markdown file.",
)
@click.option(
    "--plot",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="PNG of jawOpen, recorded and predicted, on one utterance of the split.",
)
@click.option("--plot-utterance", default=None, help="Utterance id to plot [default: the split's first].")
@click.option(
    "--report",
    "report_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Also write a report folder: report.html with the tables, a repeated-measures ANOVA of "
    "per-utterance jawOpen RMSE with pairwise tests and the figures (PNG and SVG), and every "
    "score as CSV and JSON (docs/evaluation.md).",
)
@corpus_language_option
@cache_option
@quiet_option
def evaluate_command(
    corpus_dir: Path,
    split: str,
    model_specs: tuple[str, ...],
    channels: str | None,
    postprocessing: str,
    transcript: bool,
    sync: bool,
    markdown: Path | None,
    plot: Path | None,
    plot_utterance: str | None,
    report_dir: Path | None,
    language: str,
    cache: Path | None,
    quiet: bool,
) -> None:
    """Score models against the recorded tracks of a corpus split.

    Prints, per model and channel, MSE, RMSE as % of the target's range and Pearson r over
    the speech span of each utterance, and per model the lip-closure figures.
    """
    from vispeech.evaluation.report import evaluate_models, predict_on_frames
    from vispeech.models.registry import PRETRAINED, load_model
    from vispeech.pipeline import DEFAULT_MODEL

    models = {}
    specs = [name for spec in model_specs for name in (PRETRAINED if spec == "shipped" else [spec])]
    if report_dir is not None:
        from vispeech.evaluation.report_folder import REPORT_FILES

        check_output_dir(report_dir, replaces=REPORT_FILES)
    for path in (markdown, plot):
        if path is not None:
            check_output_file(path)  # before the evaluation, not after it
    for spec in specs:
        if spec in models:
            raise VispeechError(f"model {spec!r} given twice")
        models[spec] = load_model(spec)
    wanted = None if channels is None else [c.strip() for c in channels.split(",") if c.strip()]
    aligned = read_aligned_corpus(corpus_dir, language, cache, not quiet)
    corpus = aligned.split(split)
    if not len(corpus):
        raise VispeechError(f"the {split} split of corpus {aligned.name} has no utterances")
    example = corpus[plot_utterance] if plot_utterance is not None else corpus[0]
    evaluation = evaluate_models(
        corpus,
        models,
        channels=wanted,
        postprocessing=postprocessing,
        transcript=transcript,
        sync=load_model(DEFAULT_MODEL) if sync else None,
        progress=not quiet,
    )
    click.echo(evaluation.to_text(), nl=False)
    if markdown is not None:
        with atomic_output_file(markdown) as tmp:
            tmp.write_text(evaluation.to_markdown(), encoding="utf-8")
        click.echo(f"tables -> {markdown}")
    if plot is not None or report_dir is not None:
        lag = round(evaluation.lags[example.id] * recorded_track(example).fps) if evaluation.lags is not None else 0
        predictions = {
            label: predict_on_frames(model, example, postprocessing, transcript, lag) for label, model in models.items()
        }
    if plot is not None:
        from vispeech.evaluation.plots import plot_utterance as draw

        jaw = "jawOpen" in corpus.channels and any("jawOpen" in m.channels for m in models.values())
        channel = "jawOpen" if jaw else evaluation.models[0].scores.channels[0]
        draw(example, predictions, plot, channel)
        click.echo(f"{channel} of {example.id} -> {plot}")
    if report_dir is not None:
        import shlex
        import sys

        from vispeech.evaluation.report_folder import write_report

        command = shlex.join(["vispeech", *sys.argv[1:]]) if sys.argv[1:2] == ["evaluate"] else ""
        write_report(evaluation, report_dir, example=example, predictions=predictions, command=command)
        click.echo(f"report -> {report_dir}/report.html")
