"""A study's analysis as a folder (``vispeech study analyse -o DIR``): ``analysis.json``, each
task's CSV tables and figures, and ``report.html`` (docs/study.md)."""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vispeech.evaluation.report_parts import html_figure, html_page, html_table, p_text, save_figure, write_csv
from vispeech.files import atomic_output_dir
from vispeech.study.analysis import (
    ALL_SENTENCES,
    ALPHA,
    FIXED_FORMULA,
    SENTENCE_FORMULA,
    StudyAnalysis,
    TaskAnalysis,
    p_phrase,
    proportional_odds_phrase,
)
from vispeech.study.answers import TASKS

_TABLES = (
    "coefficients",
    "random",
    "anova",
    "pairs",
    "probabilities",
    "means",
    "sentences",
    "wins",
    "proportional_odds",
)
_FIGURES = ("probabilities", "wins")
ANALYSIS_FILES = (
    "analysis.json",
    "report.html",
    *(f"{task}_{name}.csv" for task in TASKS for name in _TABLES),
    *(f"{task}_{name}.{kind}" for task in TASKS for name in _FIGURES for kind in ("png", "svg")),
)
"""What an analysis folder may hold."""


def write_analysis(analysis: StudyAnalysis, out_dir: str | os.PathLike, command: str = "") -> Path:
    """Write ``analysis`` to the folder ``out_dir``, whole or not at all: ``analysis.json``
    (everything), per task (``rating_``, ``pairwise_``) the CSV tables ``coefficients``,
    ``random``, ``anova``, ``pairs``, ``probabilities``, ``means``, ``sentences``, ``wins`` and
    ``proportional_odds``, the figures ``probabilities`` and ``wins`` (PNG and SVG), and
    ``report.html``; ``command`` is shown as how to rebuild it."""
    with atomic_output_dir(out_dir, replaces=ANALYSIS_FILES) as staging:
        (staging / "analysis.json").write_text(
            json.dumps(analysis.as_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        figures = []
        for name, task in analysis.tasks.items():
            for table, (header, rows) in _tables(task).items():
                write_csv(staging / f"{name}_{table}.csv", header, rows)
            figures += _figures(task, staging)
        (staging / "report.html").write_text(_html(analysis, figures, command), encoding="utf-8")
    return Path(out_dir)


def _tables(task: TaskAnalysis) -> dict[str, tuple[list[str], list[list]]]:
    """Each CSV table of ``task``: name → (header, rows)."""
    fit, po = task.fit, task.proportional_odds
    coefficients = [["threshold", c["name"], c["estimate"], c["se"], c["z"], ""] for c in fit.get("thresholds", [])]
    coefficients += [["fixed", c["name"], c["estimate"], c["se"], c["z"], c["p"]] for c in fit.get("fixed", [])]
    sentences = [
        [s, f["formula"], p["a"], p["b"], p["estimate"], p["se"], p["z"], p["p"], ""]
        for s, f in task.sentence_fits.items()
        for p in f.get("pairs", [])
    ]
    sentences += [
        [s, "", "", "", None, None, None, None, f["error"]]
        for s, f in task.sentence_fits.items()
        if not f.get("formula")
    ]
    tests = [
        [kind, "x", t["df"], t["lrt"], t["p"], "yes" if t["p"] is not None and t["p"] >= ALPHA else "no"]
        for kind, t in (("nominal", po["nominal"]), ("scale", po["scale"]))
        if t
    ]
    return {
        "coefficients": (["kind", "name", "estimate", "se", "z", "p"], coefficients),
        "random": (
            ["group", "term", "variance", "sd"],
            [[r["group"], r["term"], r["variance"], r["sd"]] for r in fit.get("random", [])],
        ),
        "anova": (
            ["formula", "term", "chisq", "df", "p"],
            [[fit["formula"], a["term"], a["chisq"], a["df"], a["p"]] for a in fit.get("anova", [])],
        ),
        "pairs": (
            ["a", "b", "estimate", "se", "z", "p_tukey"],
            [[p["a"], p["b"], p["estimate"], p["se"], p["z"], p["p"]] for p in fit.get("pairs", [])],
        ),
        "probabilities": (
            ["model", task.response, "probability", "se", "lower", "upper"],
            [
                [p["level"], p["response"], p["probability"], p["se"], p["lower"], p["upper"]]
                for p in fit.get("probabilities", [])
            ],
        ),
        "means": (
            ["model", "mean", "se", "lower", "upper"],
            [[m["level"], m["mean"], m["se"], m["lower"], m["upper"]] for m in fit.get("means", [])],
        ),
        "sentences": (["sentence", "formula", "a", "b", "estimate", "se", "z", "p_tukey", "error"], sentences),
        "wins": (list(task.wins.columns), task.wins.values.tolist()),
        "proportional_odds": (["test", "term", "df", "lrt", "p", "passes"], tests),
    }


def _figures(task: TaskAnalysis, folder: Path) -> list[tuple[str, str]]:
    """Draw ``task``'s figures into ``folder`` (PNG and SVG); (file stem, caption) of each."""
    drawn = []
    probabilities = task.fit.get("probabilities", [])
    if probabilities:
        drawn.append(_probabilities_figure(task, probabilities, folder))
    pairs = task.wins[["a", "b"]].drop_duplicates().values.tolist()
    if pairs:
        drawn.append(_wins_figure(task, pairs, folder))
    return drawn


def _probabilities_figure(task: TaskAnalysis, probabilities: list[dict], folder: Path) -> tuple[str, str]:
    """The inferred probability of each response level per model, with its CI."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    levels = list(dict.fromkeys(p["response"] for p in probabilities))
    figure = Figure(figsize=(max(6.0, 0.75 * len(levels) + 3.5), 4.2), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    width = 0.7 / len(task.models)
    for i, model in enumerate(task.models):
        rows = [next(p for p in probabilities if p["level"] == model and p["response"] == level) for level in levels]
        x = np.arange(len(levels)) + (i - (len(task.models) - 1) / 2) * width
        y = np.array([r["probability"] for r in rows], dtype=float)
        low = np.clip([np.nan if r["lower"] is None else r["lower"] for r in rows], 0, 1)
        high = np.clip([np.nan if r["upper"] is None else r["upper"] for r in rows], 0, 1)
        axes.errorbar(x, y, yerr=[y - low, high - y], marker="o", markersize=4, linewidth=1, capsize=3, label=model)
    axes.set_xticks(np.arange(len(levels)), levels)
    axes.set_xlabel(task.response)
    axes.set_ylabel("inferred probability (95 % CI)")
    axes.set_ylim(bottom=0)
    axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="model")
    axes.set_title(f"{task.task}: {task.fit['formula']}", fontsize=9)
    figure.tight_layout()
    save_figure(figure, folder / f"{task.task}_probabilities")
    caption = (
        f"{task.task}: the inferred probability of each {task.response} per model, with 95 % "
        "confidence intervals (at random effects 0)"
    )
    return f"{task.task}_probabilities", caption


def _wins_figure(task: TaskAnalysis, pairs: list[list[str]], folder: Path) -> tuple[str, str]:
    """Each pair's wins, ties and losses as stacked shares per sentence and over all."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    columns = min(3, len(pairs))
    grid_rows = math.ceil(len(pairs) / columns)
    names = [*task.sentences, ALL_SENTENCES]
    figure = Figure(figsize=(4.2 * columns, (0.28 * len(names) + 1.3) * grid_rows), dpi=100)
    FigureCanvasAgg(figure)
    y = np.arange(len(names))[::-1] + np.r_[np.full(len(names) - 1, 0.6), 0.0]  # the total set apart
    for k, (a, b) in enumerate(pairs):
        axes = figure.add_subplot(grid_rows, columns, k + 1)
        counts = task.wins[(task.wins["a"] == a) & (task.wins["b"] == b)].set_index("sentence").loc[names]
        total = counts[["a_wins", "ties", "b_wins"]].sum(axis=1).replace(0, 1).to_numpy()
        left = np.zeros(len(names))
        for column, label, colour in (
            ("a_wins", f"{a} better", "tab:blue"),
            ("ties", "tie", "0.75"),
            ("b_wins", f"{b} better", "tab:orange"),
        ):
            share = counts[column].to_numpy() / total
            axes.barh(y, share, left=left, color=colour, label=label, height=0.75)
            for yy, x0, w, n in zip(y, left, share, counts[column]):
                if n and w > 0.06:
                    axes.text(x0 + w / 2, yy, str(n), ha="center", va="center", fontsize=7)
            left += share
        axes.set_yticks(y, names, fontsize=7)
        axes.set_ylim(-0.6, y[0] + 0.6)
        axes.set_xlim(0, 1)
        axes.set_xlabel("share of trials", fontsize=8)
        axes.tick_params(axis="x", labelsize=7)
        axes.legend(
            fontsize=7,
            ncol=3,
            loc="lower center",
            bbox_to_anchor=(0.5, 1.0),
            frameon=False,
            handlelength=1.2,
            columnspacing=1.0,
        )
    figure.tight_layout()
    save_figure(figure, folder / f"{task.task}_wins")
    caption = (
        f"{task.task}: wins, ties and losses of each pair of models per sentence and over all "
        f"({'higher rating' if task.task == 'rating' else 'preferred'} in one trial)"
    )
    return f"{task.task}_wins", caption


def _html_table(header: Sequence[str], rows: list[list]) -> str:
    """:func:`~vispeech.evaluation.report_parts.html_table` of rows whose missing numbers are None."""
    return html_table(header, [[math.nan if v is None else v for v in row] for row in rows])


def _html_p(p: float | None) -> str:
    return "–" if p is None else p_text(p)


def _html(analysis: StudyAnalysis, figures: list[tuple[str, str]], command: str) -> str:
    e = analysis.exclusions
    parts = [
        "<h1>Perceptual study analysis</h1>",
        f"<p>Left out of the fits: {e.warmup_rows} warm-up rows, {e.check_rows} check rows"
        + (f", the {len(e.participants)} participants who failed a check" if e.participants else "")
        + f". R {html.escape(analysis.versions.get('R', '?'))}, ordinal "
        f"{html.escape(analysis.versions.get('ordinal', '?'))}, "
        f"car {html.escape(analysis.versions.get('car', '?'))}"
        f", emmeans {html.escape(analysis.versions.get('emmeans', '?'))}.</p>",
    ]
    if command:
        parts.append(f"<p>Rebuild with: <code>{html.escape(command)}</code></p>")
    if e.checks:
        parts.append(
            _html_table(
                ["check", "passed", "failed", "not shown"],
                [[name, c["passed"], c["failed"], c["none"]] for name, c in e.checks.items()],
            )
        )
    for t in analysis.tasks.values():
        parts += _html_task(t, figures)
    return html_page("vispeech study analysis", parts)


def _html_task(t: TaskAnalysis, figures: list[tuple[str, str]]) -> list[str]:
    """The page's section on one task, its figures among ``figures``."""
    parts = [
        f"<h2>{html.escape(t.task)}: {t.answers} answers by {t.participants} participants on "
        f"{len(t.sentences)} sentences</h2>"
    ]
    if t.task == "pairwise":
        parts.append("<p>Each answer gives each of its two models points: win 2, tie 1, loss 0.</p>")
    parts += [f"<p class='warning'>{html.escape(w)}</p>" for w in t.warnings]
    if t.fit.get("formula"):
        parts += _html_fit(t)
    if t.proportional_odds["nominal"] or t.proportional_odds["scale"]:
        parts.append(
            f"<p>Proportional odds (nominal_test and scale_test of the clm of <code>{FIXED_FORMULA}"
            f"</code>): {html.escape(proportional_odds_phrase(t.proportional_odds))}.</p>"
        )
    per_sentence = [
        [s, f["formula"], p["a"], p["b"], p["estimate"], _html_p(p["p"])]
        for s, f in t.sentence_fits.items()
        for p in f.get("pairs", [])
    ]
    if per_sentence:
        parts.append(
            f"<p>Per sentence (<code>{SENTENCE_FORMULA}</code>, or <code>{FIXED_FORMULA}</code> where "
            "that cannot be fitted):</p>"
        )
        parts.append(_html_table(["sentence", "model", "a", "b", "estimate", "p (Tukey)"], per_sentence))
    parts.append("<p>Wins, ties and losses (a wins: a scored higher than b in one trial):</p>")
    parts.append(_html_table(list(t.wins.columns), t.wins.values.tolist()))
    parts += [html_figure(stem, caption) for stem, caption in figures if stem.startswith(f"{t.task}_")]
    return parts


def _html_fit(t: TaskAnalysis) -> list[str]:
    """The page's account of a task's fitted model: its fit, Wald test, pairs, means and coefficients."""
    fit, c = t.fit, t.fit["convergence"]
    parts = [
        f"<p>Cumulative-link mixed model <code>{html.escape(fit['formula'])}</code> "
        f"(y: {t.response}, x: model, u: participant, s: sentence; ordinal::clmm, logit link): "
        f"{fit['nobs']:g} observations, log-likelihood {fit['log_lik']:.2f}, optimiser "
        f"{html.escape(str(c['message']))}, max |gradient| {c['max_grad']:.2g}, condition number of "
        f"the Hessian {c['cond_h']:.3g}.</p>"
    ]
    w = t.wald
    if w is not None:
        parts.append(
            f"<p><b>Do the models differ?</b> Wald χ²({w['df']:g}) = {w['chisq']:.2f}, "
            f"p {html.escape(p_phrase(w['p']))} (car::Anova, type II).</p>"
        )
    parts.append(
        "<p>Pairs (emmeans, Tukey-adjusted; estimate: a − b on the latent logit scale, positive "
        f"when a gets higher {t.response}):</p>"
    )
    parts.append(
        _html_table(
            ["a", "b", "estimate", "SE", "z", "p (Tukey)"],
            [[p["a"], p["b"], p["estimate"], p["se"], p["z"], _html_p(p["p"])] for p in fit.get("pairs", [])],
        )
    )
    parts.append(f"<p>Inferred mean {t.response} per model (95 % CI):</p>")
    parts.append(
        _html_table(
            ["model", "mean", "SE", "lower", "upper"],
            [[m["level"], m["mean"], m["se"], m["lower"], m["upper"]] for m in fit.get("means", [])],
        )
    )
    parts.append("<p>Coefficients (thresholds θ: logit P(y ≤ k) = θ<sub>k</sub> − x's effect):</p>")
    parts.append(
        _html_table(
            ["kind", "name", "estimate", "SE", "z", "p"],
            [
                [r[0], r[1], r[2], r[3], r[4], _html_p(r[5]) if r[5] != "" else ""]
                for r in _tables(t)["coefficients"][1]
            ],
        )
    )
    parts.append(
        _html_table(
            ["group", "term", "variance", "SD"],
            [[r["group"], r["term"], r["variance"], r["sd"]] for r in fit.get("random", [])],
        )
    )
    if fit.get("correlations"):
        parts.append(
            _html_table(
                ["group", "a", "b", "correlation"],
                [[r["group"], r["a"], r["b"], r["r"]] for r in fit["correlations"]],
            )
        )
    return parts
