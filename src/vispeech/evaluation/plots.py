"""Plots of recorded against predicted curves (matplotlib, Agg; written as PNG)."""

from __future__ import annotations

import math
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


ROW_SECONDS = 4.0
"""The longest stretch of an utterance :func:`plot_utterance` draws on one row (its phones legible)."""


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
    top; a long utterance is drawn in rows of at most :data:`ROW_SECONDS`, one below the other.
    Writes a PNG (an SVG when ``path`` ends in ``.svg``) at ``path`` atomically and returns the path.
    """
    figure = utterance_figure(utterance, predictions, channel)
    with atomic_output_file(path) as tmp:
        figure.savefig(tmp, format="svg" if str(path).lower().endswith(".svg") else "png")
    return Path(path)


def utterance_figure(utterance: Utterance, predictions: Mapping[str, Track], channel: str = "jawOpen") -> Figure:
    """The figure :func:`plot_utterance` writes."""
    import textwrap

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    drawn = {label: track for label, track in predictions.items() if channel in track.channels}
    if not drawn:
        raise VispeechError(f"no model predicts {channel!r}: nothing to plot")
    target = target_track(utterance, [channel])
    times = target.times
    rows = max(1, math.ceil((times[-1] - times[0]) / ROW_SECONDS - 1e-9))
    figure = Figure(figsize=(10, 1.0 + 3.0 * rows), dpi=100)
    FigureCanvasAgg(figure)
    scored = scored_frames(utterance)
    spoken = [p for p in utterance.phones if not p.is_silence] if utterance.phones is not None else []
    low = min(float(np.nanmin(target[channel])), *(float(np.nanmin(t[channel])) for t in drawn.values()))
    high = max(float(np.nanmax(target[channel])), *(float(np.nanmax(t[channel])) for t in drawn.values()))
    margin = 0.05 * (high - low or 1.0)
    span = times[scored][[0, -1]] if scored.any() else None
    for row, axes in enumerate(figure.subplots(rows, 1, squeeze=False)[:, 0]):
        start = times[0] + row * ROW_SECONDS
        end = min(times[-1], start + ROW_SECONDS) if rows > 1 else times[-1]
        if span is not None:
            axes.axvspan(*span, color="0.93", zorder=0, label="scored span")
        axes.plot(times, target[channel], color="black", linewidth=2.0, label="recorded")
        for label, track in drawn.items():
            axes.plot(track.times, track[channel], linewidth=1.2, label=label)
        here = [p for p in spoken if start <= (p.start + p.end) / 2 <= end]
        if spoken:
            top = axes.secondary_xaxis("top")
            # every other label a line higher: fast speech's phones do not overprint each other
            labels = [p.symbol + "\n" * (k % 2) for k, p in enumerate(here)]
            top.set_xticks([(p.start + p.end) / 2 for p in here], labels, fontsize=7)
            for boundary in np.unique([p.start for p in here]):
                axes.axvline(boundary, color="0.85", linewidth=0.5, zorder=0)
        axes.set_xlim(start, start + ROW_SECONDS if rows > 1 else end)
        axes.set_ylim(low - margin, high + margin)
        axes.set_ylabel(channel)
        if row == 0:
            axes.legend(fontsize=8, loc="upper right")
        if row == rows - 1:
            axes.set_xlabel("time (s)")
    title = textwrap.shorten(f"{utterance.id}: {utterance.text}", width=300, placeholder=" …")
    figure.suptitle("\n".join(textwrap.wrap(title, width=110)), fontsize=9)
    figure.tight_layout()
    return figure


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
