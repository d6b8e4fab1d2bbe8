"""``vispeech train``: fit a model on a corpus and save it."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import TYPE_CHECKING

import click

from vispeech.cli import main, quiet_option
from vispeech.cli._corpus_input import cache_option, corpus_language_option, corpus_option, read_aligned_corpus
from vispeech.errors import VispeechError

if TYPE_CHECKING:
    from vispeech.models.contract import Estimator

CHECKPOINT = "checkpoint"
"""Sub-folder of the output folder where a network's training state is kept after every epoch."""

_TARGETS = {"arkit": "mouth", "articulatory": "articulatory"}
LOSS_CURVE = "loss_curve.png"
"""The loss curve train draws beside the saved model."""


@main.command("train")
@corpus_option
@click.option(
    "--model",
    "-m",
    "model_name",
    default=None,
    help="Model family to fit: tdnn-beskow, tdnn-lowlatency, sliding-window-thesis, sliding-window-taylor, "
    "sliding-window-dtree, lstm-taylor, "
    "cohen-massaro, ohman (phones in), audio-cnn, audio-encdec (audio in).",
)
@click.option(
    "--from",
    "from_model",
    default=None,
    metavar="MODEL",
    help="Adapt this trained network (a shipped name such as grid-tdnn or grid-audio-cnn, or a saved folder) "
    "to the corpus instead: it starts from its weights (speaker adaptation).",
)
@click.option("--epochs", type=click.IntRange(min=1), default=None, help="Most epochs in all [default: the model's].")
@click.option("--seed", type=int, default=None, help="Random seed [default: the model's].")
@click.option(
    "--input",
    "inputs",
    type=click.Choice(["phones", "features"]),
    default=None,
    help="Phone one-hot vectors or articulatory feature vectors [default: the model's].",
)
@click.option(
    "--targets",
    type=click.Choice(list(_TARGETS)),
    default=None,
    help="ARKit mouth channels or articulatory parameters measured on landmarks [default: the model's].",
)
@click.option(
    "--param",
    "-p",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="Set any hyper-parameter of the model (docs/networks.md), e.g. --param features=encoder "
    "--param encoder=/models/wavlm-base-plus; VALUE is read as JSON (numbers, lists, true, null) "
    "or else taken as text. Repeatable.",
)
@click.option(
    "--resume",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Go on from a saved model or an interrupted run's output folder.",
)
@click.option(
    "--output",
    "-o",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder to save the trained model in.",
)
@corpus_language_option
@cache_option
@quiet_option
def train_command(
    corpus_dir: Path,
    model_name: str | None,
    from_model: str | None,
    epochs: int | None,
    seed: int | None,
    inputs: str | None,
    targets: str | None,
    params: tuple[str, ...],
    resume: Path | None,
    out_dir: Path,
    language: str,
    cache: Path | None,
    quiet: bool,
) -> None:
    """Fit a model on the train split of a corpus (validation split for early stopping) and save it.

    A network keeps its training state in OUTPUT/checkpoint after every epoch, so an
    interrupted run goes on with --resume OUTPUT; the folder is removed once the model is saved.
    The loss curve is drawn into OUTPUT/loss_curve.png. With --from MODEL a trained network (phones
    or audio in) is adapted to the corpus (a new speaker: minutes of takes), and its test-split score before
    adaptation is printed beside the one after.
    """
    from vispeech.files import check_output_dir
    from vispeech.models.networks.network import Network
    from vispeech.models.persistence import FOLDER_NAMES
    from vispeech.models.registry import FAMILIES, family_class

    if (model_name is None) == (from_model is None):
        raise VispeechError("give --model FAMILY to train one afresh, or --from MODEL to adapt a trained one")
    check_output_dir(out_dir, replaces=FOLDER_NAMES)  # before the training, not after it
    if from_model is not None:
        _adapt(from_model, corpus_dir, epochs, seed, inputs, targets, params, resume, out_dir, language, cache, quiet)
        return
    if model_name not in FAMILIES:
        trainable = ", ".join(name for name in FAMILIES if family_class(name).trainable)
        raise VispeechError(f"unknown model family {model_name!r} (train one of: {trainable})")
    cls = family_class(model_name)
    if not cls.trainable:
        if cls.data_free:
            raise VispeechError(f"model {model_name} is data-free: its parameters are authored, not fitted")
        raise VispeechError(f"model {model_name} learns nothing itself: train the models it combines")
    options = _model_options(cls, model_name, epochs, seed, inputs, targets, params)
    neural = issubclass(cls, Network)
    if resume is not None and not neural:
        raise VispeechError(f"--resume needs a network; model {model_name} is fitted in one go")
    if resume is not None:  # the run's own parameters, but for those given again (its budget, say)
        run = _run_to_resume(resume)
        assert run is not None  # resume is given
        options = {**cls.load(run).get_params(), **options}
    checkpoint = out_dir / CHECKPOINT if neural else None
    model = cls(**options)

    from vispeech.corpus.corpus import frame_rates_text

    corpus = read_aligned_corpus(corpus_dir, language, cache, not quiet)
    if options.get("targets") == "articulatory":
        from vispeech.corpus import with_articulatory_tracks

        corpus = with_articulatory_tracks(corpus)
    sizes = {name: len(corpus.split(name)) for name in ("train", "validation", "test")}
    if not sizes["train"]:
        raise VispeechError(f"the train split of corpus {corpus.name} has no utterances")
    click.echo(
        f"{corpus.name}: train {sizes['train']}, validation {sizes['validation']}, test {sizes['test']} "
        f"utterances at {frame_rates_text(corpus.frame_rates)} fps"
    )

    model.fit(corpus, progress=not quiet, checkpoint_dir=checkpoint, resume_from=_run_to_resume(resume))
    _save(model, corpus, out_dir)


def _model_options(
    cls: type[Estimator],
    model_name: str,
    epochs: int | None,
    seed: int | None,
    inputs: str | None,
    targets: str | None,
    params: tuple[str, ...],
) -> dict[str, object]:
    """The hyper-parameters the command line gives a model of family ``cls``: its flags, then ``--param``s."""
    given: dict[str, tuple[str, object]] = {
        "--epochs": ("epochs", epochs),
        "--seed": ("seed", seed),
        "--input": ("inputs", inputs),
        "--targets": ("targets", None if targets is None else _TARGETS.get(targets)),
    }
    options: dict[str, object] = {}
    for flag, (key, value) in given.items():
        if value is None:
            continue
        if key not in cls.defaults:
            raise VispeechError(f"model {model_name} takes no {flag}")
        options[key] = value
    for key, value in map(_parameter, params):
        if key not in cls.defaults:
            raise VispeechError(f"model {model_name} takes no parameter {key!r}")
        if key in options:
            raise VispeechError(f"{key} is given twice")
        options[key] = value
    return options


def _run_to_resume(resume: Path | None) -> Path | None:
    """The run ``--resume`` names: an interrupted run's checkpoint in its output folder, or a saved model."""
    if resume is None:
        return None
    return resume / CHECKPOINT if (resume / CHECKPOINT / "config.json").is_file() else resume


def _adapt(
    from_model: str,
    corpus_dir: Path,
    epochs: int | None,
    seed: int | None,
    inputs: str | None,
    targets: str | None,
    params: tuple[str, ...],
    resume: Path | None,
    out_dir: Path,
    language: str,
    cache: Path | None,
    quiet: bool,
) -> None:
    """``train --from``: the trained network, warm-started on the corpus, saved; scores before and after."""
    from vispeech.models.networks.network import Network
    from vispeech.models.registry import load_model

    if inputs is not None or targets is not None or resume is not None:
        raise VispeechError(
            "--from keeps the model's inputs and targets and starts afresh: no --input, --targets or --resume"
        )
    base = load_model(from_model)
    if not isinstance(base, Network):
        raise VispeechError(
            f"--from needs a trained network (phones or audio); {from_model!r} is a {base.family} model"
        )
    options: dict[str, object] = {
        key: value for key, value in (("epochs", epochs), ("seed", seed)) if value is not None
    }
    for key, value in map(_parameter, params):
        if key not in base.get_params():
            raise VispeechError(f"model {base.family} takes no parameter {key!r}")
        options[key] = value
    model = copy.deepcopy(base).set_params(**options)
    corpus = read_aligned_corpus(corpus_dir, language, cache, not quiet)
    if not len(corpus.split("train")):
        raise VispeechError(f"the train split of corpus {corpus.name} has no utterances")
    click.echo(
        f"{corpus.name}: adapting {base.name} on {len(corpus.split('train'))} utterances "
        f"(validation {len(corpus.split('validation'))}, test {len(corpus.split('test'))})"
    )
    click.echo(f"before: {_test_score(base, corpus)}")
    model.fit(corpus, progress=not quiet, checkpoint_dir=out_dir / CHECKPOINT, warm_start=True)
    _save(model, corpus, out_dir)


def _save(model, corpus, out_dir: Path) -> None:
    """Save a fitted model as ``out_dir`` (named after it; the new folder replaces the old with
    its training checkpoint), draw its loss curve and print the summary."""
    model.save(out_dir, name=out_dir.name)
    if model.history_.epochs:
        from vispeech.evaluation.plots import plot_history

        plot_history(model.history_, out_dir / LOSS_CURVE)
    _summary(model, corpus, out_dir)


def _test_score(model, corpus) -> str:
    """The model's jawOpen score on the corpus's test split, without post-processing, as text."""
    from vispeech.evaluation.report import available_channels, evaluate_models

    test = corpus.split("test")
    shared = [c for c in ("jawOpen", "jaw_opening") if c in model.channels and c in available_channels(test)]
    if not len(test):
        return "test split: no utterances to score"
    if not shared:
        return "test split: no jaw channel to score"
    result = (
        evaluate_models(test, {model.name: model}, channels=shared[:1], postprocessing="none")
        .models[0]
        .scores[shared[0]]
    )
    return (
        f"test split ({len(test)} utterances, no post-processing): {shared[0]} r {result['r']:.3f}, "
        f"RMSE {result['rmse_percent']:.2f} % of range, MSE {result['mse']:.5f}"
    )


def _parameter(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` as the key and the value read as JSON (else the text itself)."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise VispeechError(f"--param takes KEY=VALUE, got {text!r}")
    try:
        return key.strip(), json.loads(value)
    except json.JSONDecodeError:
        return key.strip(), value


def _summary(model, corpus, out_dir: Path) -> None:
    """Print what fitting did and the model's jaw scores on the test split."""
    click.echo(f"saved {model.name} -> {out_dir}")
    history = model.history_
    if history.epochs:
        best = history.best_epoch
        loss = history.validation_loss[best - 1]
        which = "validation"
        if loss is None:
            loss, which = history.train_loss[best - 1], "training"
        click.echo(f"epochs: {history.epochs}, best {best} ({which} loss {loss:.4g}), {sum(history.seconds):.1f} s")
    if (out_dir / LOSS_CURVE).is_file():
        click.echo(f"loss curve -> {out_dir / LOSS_CURVE}")
    click.echo(_test_score(model, corpus))
