"""Error against one hyper-parameter: the look-ahead of a low-latency network (Beskow 2004,
Fig. 4) or the window of a sliding-window network (Taylor et al. 2017, Fig. 11).

:func:`sweep` trains one model of a family per value of a hyper-parameter, on the same training
split, and scores each on the test split (raw output, no post-processing: the figure is about
the model); :func:`plot_sweep` draws jawOpen's RMSE and r against the value (PNG and SVG).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, cast

from vispeech.corpus.corpus import Corpus
from vispeech.errors import VispeechError
from vispeech.evaluation.report import evaluate_models
from vispeech.models.history import TrainingHistory

SWEEPS = {
    "look-ahead": ("tdnn-lowlatency", "look_ahead"),
    "window": ("sliding-window-taylor", "input_window"),
}
"""What ``vispeech sweep`` varies: name → (default family, hyper-parameter)."""


class _Trained(Protocol):
    """A model trained in epochs (the networks, the decision tree): its training history."""

    history_: TrainingHistory
    fps_: float


@dataclass(frozen=True)
class SweepPoint:
    """One trained model of a sweep: the ``value``, its test-split jawOpen RMSE (% of range) and
    r, the epochs it trained, the seconds that took and the frame rate it ran at (the value's
    frames are frames at that rate)."""

    value: int
    rmse_percent: float
    r: float
    epochs: int
    seconds: float
    fps: float


def sweep(
    corpus: Corpus,
    family: str,
    parameter: str,
    values: Sequence[int],
    params: dict | None = None,
    progress: Callable[[str], None] | None = None,
    fit_progress: bool = False,
) -> list[SweepPoint]:
    """Train ``family`` on ``corpus``'s train split (validation split for early stopping) once per
    value of ``parameter`` (other hyper-parameters: ``params``) and score jawOpen on the test split.

    Every value's model is made (its parameters checked) before the first is trained; a value
    given twice is an error. ``progress`` is told each value's scores, ``fit_progress`` shows each
    fit's progress bar."""
    import time

    from vispeech.models.registry import create_model

    test = corpus.split("test")
    if not len(test) or not len(corpus.split("train")):
        raise VispeechError(f"corpus {corpus.name} needs train and test utterances for a sweep")
    twice = next((v for v in values if list(values).count(v) > 1), None)
    if twice is not None:
        raise VispeechError(f"{parameter}={twice} is given twice")
    models = [create_model(family, **{**(params or {}), parameter: value}) for value in values]
    points = []
    for value, model in zip(values, models):
        started = time.perf_counter()
        model.fit(corpus, progress=fit_progress)
        seconds = time.perf_counter() - started
        scores = (
            evaluate_models(test, {f"{parameter}={value}": model}, channels=["jawOpen"], postprocessing="none")
            .models[0]
            .scores["jawOpen"]
        )
        trained = cast(_Trained, model)
        point = SweepPoint(value, scores["rmse_percent"], scores["r"], trained.history_.epochs, seconds, trained.fps_)
        points.append(point)
        if progress is not None:
            progress(
                f"{parameter}={value}: jawOpen RMSE {point.rmse_percent:.2f} %, r {point.r:.3f} "
                f"({point.epochs} epochs, {seconds:.0f} s)"
            )
    return points


def plot_sweep(
    points: Sequence[SweepPoint],
    parameter: str,
    family: str,
    out_stem: str | os.PathLike,
) -> list[Path]:
    """jawOpen's RMSE (left axis) and r (right axis) against the value (frames at the models'
    rate): ``out_stem``.png and .svg."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6, 4), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    values = [p.value for p in points]
    axes.plot(values, [p.rmse_percent for p in points], "o-", color="tab:blue", label="RMSE")
    rates = sorted({p.fps for p in points})
    unit = f"frames at {rates[0]:g} fps" if len(rates) == 1 else "frames"
    axes.set_xlabel(f"{parameter.replace('_', ' ')} ({unit})")
    axes.set_ylabel("jawOpen RMSE, % of range", color="tab:blue")
    right = axes.twinx()
    right.plot(values, [p.r for p in points], "s--", color="tab:red", label="r")
    right.set_ylabel("jawOpen r", color="tab:red")
    axes.set_title(f"{family}: test split, raw output", fontsize=9)
    figure.tight_layout()
    stem = Path(out_stem)
    written = []
    for kind in ("png", "svg"):
        path = stem.with_suffix(f".{kind}")
        figure.savefig(path, format=kind)
        written.append(path)
    return written
