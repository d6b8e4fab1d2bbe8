"""Plots of recorded against predicted curves (matplotlib, Agg; written as PNG)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vispeech.corpus.corpus import Utterance
from vispeech.errors import VispeechError
from vispeech.evaluation.report import scored_frames, target_track
from vispeech.files import atomic_output_file
from vispeech.models.history import TrainingHistory
from vispeech.motion.track import Track

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def plot_utterance(
    utterance: Utterance,
    predictions: Mapping[str, Track],
    path: str | os.PathLike,
    channel: str = "jawOpen",
) -> Path:
    """Draw one channel of an utterance: the recorded curve and each model's (by label).

    ``predictions`` are tracks on the utterance's frames (see
    :func:`vispeech.evaluation.report.predict_on_frames`); those without ``channel`` are
    left out. The scored frames (speech span) are shaded and the phones labelled along the
    top. Writes a PNG (an SVG when ``path`` ends in ``.svg``) at ``path`` atomically and returns the path.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    target = target_track(utterance, [channel])
    times = target.times
    figure = Figure(figsize=(10, 4), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    scored = scored_frames(utterance)
    if scored.any():
        first, last = times[scored][[0, -1]]
        axes.axvspan(first, last, color="0.93", zorder=0, label="scored span")
    axes.plot(times, target[channel], color="black", linewidth=2.0, label="recorded")
    drawn = 0
    for label, track in predictions.items():
        if channel in track.channels:
            axes.plot(track.times, track[channel], linewidth=1.2, label=label)
            drawn += 1
    if not drawn:
        raise VispeechError(f"no model predicts {channel!r}: nothing to plot")
    if utterance.phones is not None:
        top = axes.secondary_xaxis("top")
        spoken = [p for p in utterance.phones if not p.is_silence]
        top.set_xticks([(p.start + p.end) / 2 for p in spoken], [p.symbol for p in spoken], fontsize=7)
        for boundary in np.unique([p.start for p in spoken]):
            axes.axvline(boundary, color="0.85", linewidth=0.5, zorder=0)
    axes.set_xlim(times[0], times[-1])
    axes.set_xlabel("time (s)")
    axes.set_ylabel(channel)
    axes.set_title(f"{utterance.id}: {utterance.text}", fontsize=9, pad=18)
    axes.legend(fontsize=8, loc="upper right")
    figure.tight_layout()
    with atomic_output_file(path) as tmp:
        figure.savefig(tmp, format="svg" if str(path).lower().endswith(".svg") else "png")
    return Path(path)


LOG_LOSS_SPAN = 3.0
"""A loss curve is drawn on a log scale when its largest loss is more than this many times its smallest."""


def plot_history(history: TrainingHistory, path: str | os.PathLike) -> Path:
    """Draw a fit's training and validation loss per epoch into a PNG at ``path``
    (:func:`history_figure`)."""
    figure = history_figure(history)
    with atomic_output_file(path) as tmp:
        figure.savefig(tmp, format="png")
    return Path(path)


def history_figure(history: TrainingHistory) -> Figure:
    """A fit's training and validation loss per epoch, on whole epochs, on a log scale when the
    losses span more than :data:`LOG_LOSS_SPAN` times."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    figure = Figure(figsize=(6, 4), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    epochs = np.arange(1, history.epochs + 1)
    axes.plot(epochs, history.train_loss, marker="o", markersize=3, label="training")
    validation = np.array([np.nan if v is None else v for v in history.validation_loss], dtype=float)
    if not np.all(np.isnan(validation)):
        axes.plot(epochs, validation, marker="o", markersize=3, label="validation")
    if history.best_epoch:
        axes.axvline(history.best_epoch, color="grey", linestyle=":", label=f"best (epoch {history.best_epoch})")
    losses = np.concatenate([history.train_loss, validation])
    losses = losses[np.isfinite(losses)]
    if losses.size and losses.min() > 0 and losses.max() > LOG_LOSS_SPAN * losses.min():
        axes.set_yscale("log")
    if history.epochs <= 10:
        axes.set_xticks(epochs)
    else:
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes.set_xlim(0.5, max(history.epochs, 1) + 0.5)
    axes.set_xlabel("epoch")
    axes.set_ylabel("loss")
    axes.legend()
    figure.tight_layout()
    return figure
