"""The evaluation report as a folder (``vispeech evaluate --report OUT``): an HTML page with the
tables and figures, and every score as CSV and JSON, so that nothing has to be copied off a
screen and the page can be rebuilt from the command line it shows.

:func:`write_report` writes, for an :class:`~vispeech.evaluation.report.Evaluation`:

- ``report.html``: the models' scores per channel, the repeated-measures ANOVA of per-utterance
  jawOpen RMSE with its pairwise comparisons (:mod:`vispeech.evaluation.statistics`), jawOpen's
  motion (lag, velocity, jerk, energy above 8 Hz) against the recording's, the lip vertex error
  in landmark space, jawOpen's RMSE by phone class, the lip closures with their timing, and the
  figures;
- ``scores.csv`` (one row per model and channel), ``utterances.csv`` (per utterance and model:
  jawOpen RMSE % and r), ``anova.csv``, ``pairs.csv`` and ``scores.json`` (all of it);
- figures, each as PNG and SVG: ``correlation`` (r per channel and model), ``utterance_rmse``
  (the spread of per-utterance jawOpen RMSE per model: what the ANOVA compares) and
  ``trajectory`` (one utterance's jawOpen, recorded and predicted, phones along the top).
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from vispeech.corpus.corpus import Utterance, frame_rates_text
from vispeech.evaluation.report import Evaluation
from vispeech.evaluation.report_parts import (
    html_figure,
    html_page,
    html_table,
    json_ready,
    p_text,
    save_figure,
    write_csv,
)
from vispeech.evaluation.statistics import Comparison, compare_models
from vispeech.files import atomic_output_dir
from vispeech.motion.track import Track

REPORT_FILES = (
    "report.html",
    "scores.csv",
    "utterances.csv",
    "anova.csv",
    "pairs.csv",
    "scores.json",
    *(f"{name}.{kind}" for name in ("correlation", "utterance_rmse", "trajectory") for kind in ("png", "svg")),
)
"""What a report folder holds."""


def write_report(
    evaluation: Evaluation,
    out_dir: str | os.PathLike,
    *,
    example: Utterance | None = None,
    predictions: Mapping[str, Track] | None = None,
    command: str = "",
) -> Path:
    """Write the report folder of ``evaluation`` (see the module docstring); ``example`` and its
    ``predictions`` (tracks on its frames, by model label) make the trajectory figure, and
    ``command`` is shown as how to rebuild the report. Written whole or not at all."""
    comparison = _comparison(evaluation)
    with atomic_output_dir(out_dir, replaces=REPORT_FILES) as staging:
        write_csv(
            staging / "scores.csv",
            ["model", "channel", "mse", "rmse_percent", "r", "utterance_mse", "utterance_rmse_percent", "utterance_r"],
            _score_rows(evaluation),
        )
        write_csv(staging / "utterances.csv", *_utterance_table(evaluation))
        if comparison is not None:
            a = comparison.anova
            write_csv(
                staging / "anova.csv",
                ["score", "F", "df_model", "df_error", "p", "partial_eta_squared", "mse", "utterances"],
                [[a.score, a.f, a.df_model, a.df_error, a.p, a.partial_eta_squared, a.mse, a.utterances]],
            )
            write_csv(
                staging / "pairs.csv",
                ["a", "b", "difference", "t", "p_lsd", "p_tukey", "d_z"],
                [[p.a, p.b, p.difference, p.t, p.p_lsd, p.p_tukey, p.d_z] for p in comparison.pairs],
            )
        (staging / "scores.json").write_text(
            json.dumps(evaluation_json(evaluation, comparison), indent=2, allow_nan=False), encoding="utf-8"
        )
        figures = _figures(evaluation, staging, example, predictions or {})
        (staging / "report.html").write_text(_html(evaluation, comparison, figures, command), encoding="utf-8")
    return Path(out_dir)


def _comparison(evaluation: Evaluation) -> Comparison | None:
    """The ANOVA of per-utterance jawOpen RMSE over the models that predict jawOpen (two or more)."""
    scores = {
        m.label: m.scores.per_utterance_rmse_percent[:, m.scores.channels.index("jawOpen")]
        for m in evaluation.models
        if "jawOpen" in m.scores.channels
    }
    if len(scores) < 2 or len(next(iter(scores.values()))) < 3:
        return None
    return compare_models(scores, "jawOpen RMSE % (per utterance)")


def _score_rows(evaluation: Evaluation) -> list[list]:
    rows = []
    for m in evaluation.models:
        for channel in m.scores.channels:
            s = m.scores[channel]
            rows.append(
                [
                    m.label,
                    channel,
                    s["mse"],
                    s["rmse_percent"],
                    s["r"],
                    s["utterance_mse"],
                    s["utterance_rmse_percent"],
                    s["utterance_r"],
                ]
            )
    return rows


def _utterance_table(evaluation: Evaluation) -> tuple[list[str], list[list]]:
    models = [m for m in evaluation.models if "jawOpen" in m.scores.channels]
    header = ["utterance", *(f"{m.label} {kind}" for m in models for kind in ("jawOpen_rmse_percent", "jawOpen_r"))]
    ids = evaluation.utterance_ids or [str(k) for k in range(len(models[0].scores.per_utterance_r) if models else 0)]
    rows = []
    for k, utterance in enumerate(ids):
        row: list = [utterance]
        for m in models:
            j = m.scores.channels.index("jawOpen")
            row += [m.scores.per_utterance_rmse_percent[k, j], m.scores.per_utterance_r[k, j]]
        rows.append(row)
    return header, rows


def evaluation_json(evaluation: Evaluation, comparison: Comparison | None = None) -> dict:
    """Every number of ``evaluation`` (and of its ``comparison``) as JSON-ready data: what
    ``scores.json`` holds."""
    models = []
    for m in evaluation.models:
        closures = None
        if m.closures is not None:
            c = m.closures
            closures = {
                "bilabials": c.bilabials,
                "tracked_closures": c.tracked_closures,
                "model_closures": c.model_closures,
                "bilabial_rate": c.bilabial_rate,
                "model_closed_share": c.model_closed_share,
                "tracked_closed_share": c.tracked_closed_share,
                "passed": c.passed,
                **c.timing(),
            }
        models.append(
            {
                "label": m.label,
                "model": m.model,
                "scores": {ch: m.scores[ch] for ch in m.scores.channels},
                "closures": closures,
                "jawOpen_dynamics": m.dynamics,
                "jawOpen_rmse_by_phone_class": m.by_phone,
                "lips": m.lips,
            }
        )
    out = {
        "corpus": evaluation.corpus,
        "frame_rates": evaluation.frame_rates,
        "utterances": evaluation.utterances,
        "postprocessing": evaluation.postprocessing,
        "models": models,
        "recorded_jawOpen_dynamics": evaluation.recorded_dynamics,
    }
    if evaluation.sync is not None:
        out["sync"] = {"model": evaluation.sync, "lags_s": evaluation.lags}
    if comparison is not None:
        out["comparison"] = {
            "means": comparison.means,
            "anova": vars(comparison.anova),
            "pairs": [vars(p) for p in comparison.pairs],
        }
    return json_ready(out)


def _figures(
    evaluation: Evaluation, folder: Path, example: Utterance | None, predictions: Mapping[str, Track]
) -> list[tuple[str, str]]:
    """Draw the figures into ``folder`` (PNG and SVG); (file stem, caption) of each."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    drawn = []
    channels = list(dict.fromkeys(c for m in evaluation.models for c in m.scores.channels))
    figure = Figure(figsize=(min(18, max(7, 0.35 * len(channels) + 5)), 4.5), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    width = 0.8 / len(evaluation.models)
    for i, m in enumerate(evaluation.models):
        values = [m.scores[c]["r"] if c in m.scores.channels else np.nan for c in channels]
        offset = (i - (len(evaluation.models) - 1) / 2) * width
        axes.bar(np.arange(len(channels)) + offset, values, width, label=m.label)
    axes.set_xticks(np.arange(len(channels)), channels, rotation=60, ha="right", fontsize=7)
    axes.set_ylabel("Pearson r (frames pooled)")
    axes.axhline(0, color="black", linewidth=0.6)
    axes.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    save_figure(figure, folder / "correlation")
    drawn.append(("correlation", "Correlation with the recording, per channel and model"))

    models = [m for m in evaluation.models if "jawOpen" in m.scores.channels]
    if models:
        figure = Figure(figsize=(max(5, 1.1 * len(models) + 2), 4.5), dpi=100)
        FigureCanvasAgg(figure)
        axes = figure.add_subplot()
        data = [m.scores.per_utterance_rmse_percent[:, m.scores.channels.index("jawOpen")] for m in models]
        axes.boxplot([d[np.isfinite(d)] for d in data], showmeans=True)
        axes.set_xticks(np.arange(1, len(models) + 1), [m.label for m in models], rotation=30, ha="right", fontsize=8)
        axes.set_ylabel("jawOpen RMSE, % of range (per utterance)")
        figure.tight_layout()
        save_figure(figure, folder / "utterance_rmse")
        drawn.append(("utterance_rmse", "Per-utterance jawOpen RMSE: what the ANOVA compares (triangles: means)"))

    if example is not None and any("jawOpen" in t.channels for t in predictions.values()):
        from vispeech.evaluation.plots import plot_utterance

        for kind in ("png", "svg"):
            plot_utterance(example, predictions, folder / f"trajectory.{kind}", "jawOpen")
        drawn.append(("trajectory", f"jawOpen of {example.id}, recorded and predicted, phones along the top"))
    return drawn


def _html(evaluation: Evaluation, comparison: Comparison | None, figures: list[tuple[str, str]], command: str) -> str:
    parts = _html_scores(evaluation, command)
    if comparison is not None:
        parts += _html_comparison(comparison)
    parts += _html_dynamics(evaluation) + _html_lips(evaluation) + _html_phone_classes(evaluation)
    parts += _html_closures(evaluation)
    parts += [html_figure(stem, caption) for stem, caption in figures]
    return html_page(f"vispeech evaluation: {evaluation.corpus}", parts)


def _html_scores(evaluation: Evaluation, command: str) -> list[str]:
    """The page's head: what was evaluated, how to rebuild it, the scores per channel."""
    parts = [
        f"<h1>Evaluation on {html.escape(evaluation.corpus)}</h1>",
        f"<p>{evaluation.utterances} utterances at {frame_rates_text(evaluation.frame_rates)} fps, "
        f"post-processing {html.escape(evaluation.postprocessing)}. "
        "RMSE is in % of the recording's range; r is Pearson's, over the speech span.</p>",
    ]
    if evaluation.sync is not None:
        parts.append(f"<p>Sound and picture {html.escape(evaluation.sync_summary())}.</p>")
    if command:
        parts.append(f"<p>Rebuild with: <code>{html.escape(command)}</code></p>")
    parts.append("<h2>Scores</h2>")
    parts.append(
        html_table(
            ["model", "channel", "MSE", "RMSE %", "r", "utt. RMSE %", "utt. r"],
            [[r[0], r[1], r[2], r[3], r[4], r[6], r[7]] for r in _score_rows(evaluation)],
        )
    )
    return parts


def _html_comparison(comparison: Comparison) -> list[str]:
    """The ANOVA over the models and its pairwise comparisons."""
    a = comparison.anova
    return [
        f"<h2>Do the models differ? {html.escape(a.score)}</h2>",
        html_table(["model", "mean"], [[k, v] for k, v in comparison.means.items()]),
        "<p>Repeated-measures ANOVA, the model as the within-utterance factor:</p>",
        html_table(
            ["F", "df", "p", "partial η²"],
            [[a.f, f"{a.df_model}, {a.df_error}", p_text(a.p), a.partial_eta_squared]],
        ),
        "<p>Pairwise (difference = a − b; LSD and Tukey from the ANOVA's error term; d<sub>z</sub>: "
        "mean paired difference over its standard deviation):</p>",
        html_table(
            ["a", "b", "difference", "t", "p (LSD)", "p (Tukey)", "d_z"],
            [[p.a, p.b, p.difference, p.t, p_text(p.p_lsd), p_text(p.p_tukey), p.d_z] for p in comparison.pairs],
        ),
    ]


def _html_dynamics(evaluation: Evaluation) -> list[str]:
    """jawOpen's motion per model against the recording's (none without both)."""
    dynamic = [(m.label, m.dynamics) for m in evaluation.models if m.dynamics]
    rec = evaluation.recorded_dynamics
    if not (dynamic and rec):
        return []
    rows = [
        ["recorded", "", rec["velocity_rms"], rec["acceleration_rms"], rec["jerk_rms"], rec["high_frequency_share"]]
    ]
    rows += [
        [label, d["lag_s"], d["velocity_rms"], d["acceleration_rms"], d["jerk_rms"], d["high_frequency_share"]]
        for label, d in dynamic
    ]
    return [
        "<h2>How jawOpen moves</h2><p>Lag: seconds the prediction trails the recording where they "
        "correlate best. Jitter shows as more jerk and energy above 8 Hz than the recording has, "
        "over-smoothing as less.</p>",
        html_table(
            ["", "lag (s)", "velocity RMS (/s)", "acceleration RMS (/s²)", "jerk RMS (/s³)", "energy above 8 Hz"],
            rows,
        ),
    ]


def _html_lips(evaluation: Evaluation) -> list[str]:
    """The lip vertex error of the models that have one."""
    lipped = [(m.label, m.lips) for m in evaluation.models if m.lips]
    if not lipped:
        return []
    return [
        "<h2>The lips in landmark space</h2><p>Lip vertex error: per frame the largest distance "
        "of the 12 lip landmarks from the tracked ones, then the mean, in eye-corner distances, "
        "through a linear read-out from blend shapes to landmarks fitted on the recording's own "
        "scores (the floor: the read-out's error on them). Aperture: mean absolute error of the "
        "inner-lip gap.</p>",
        html_table(
            ["model", "lip vertex error", "floor", "aperture error"],
            [[label, lips["lve"], lips["floor"], lips["aperture_mae"]] for label, lips in lipped],
        ),
    ]


def _html_phone_classes(evaluation: Evaluation) -> list[str]:
    """jawOpen's RMSE by phone class, per model that has it."""
    classed = [(m.label, m.by_phone) for m in evaluation.models if m.by_phone]
    if not classed:
        return []
    names = list(classed[0][1])
    return [
        "<h2>jawOpen RMSE by phone class</h2><p>% of jawOpen's range, over the scored frames "
        "that fall in phones of each class.</p>",
        html_table(["model", *names], [[label, *(by_phone[n] for n in names)] for label, by_phone in classed]),
    ]


def _html_closures(evaluation: Evaluation) -> list[str]:
    """The lip closures and their timing, per model with closure counts."""
    counted = [(m.label, m.closures) for m in evaluation.models if m.closures is not None]
    if not counted:
        return []
    rows = []
    for label, closures in counted:
        timing = closures.timing()
        rows.append(
            [
                label,
                f"{closures.tracked_closures}/{closures.bilabials}",
                f"{closures.model_closures} ({closures.bilabial_rate:.0f} %)",
                timing["onset_median_ms"],
                timing["onset_mean_abs_ms"],
                timing["release_median_ms"],
                timing["release_mean_abs_ms"],
                "yes" if closures.passed else "no",
            ]
        )
    return [
        "<h2>Lip closures</h2><p>Timing: from the start (end) of the speaker's closure over a "
        "/p b m/ to the model's, on the closures both make; positive: the model is late.</p>",
        html_table(
            [
                "model",
                "/p b m/ the speaker closes",
                "closed by the model too",
                "onset median (ms)",
                "onset mean |ms|",
                "release median (ms)",
                "release mean |ms|",
                "passed",
            ],
            rows,
        ),
    ]
