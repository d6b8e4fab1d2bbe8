"""The analysis of a perceptual study's answers (``vispeech study analyse``), as the thesis
analysed its surveys (its §6.4), with R's ``ordinal``, ``car`` and ``emmeans`` as the engine.

Each task of ``answers.csv`` (see ``docs/study.md``) is analysed on its own, warm-up showings
and check items left out:

- **rating** (1-9 per face): the rating ``y`` (an ordered factor) by the model ``x`` in a
  proportional-odds cumulative-link mixed model (``ordinal::clmm``, logit link) with random
  intercepts and model slopes per participant ``u`` and sentence ``s``, ``y ~ x + (1 + x | u) +
  (1 + x | s)`` (:data:`SLOPES_FORMULA`); when that fails (an error, no convergence, a Hessian
  without finite standard errors) the random intercepts alone, ``y ~ x + (1 | u) + (1 | s)``,
  and the results say so;
- **pairwise** (left / tie / right): each answer gives each of its two models points, win 2,
  tie 1, loss 0 (:data:`POINTS`), and the points are analysed as the ratings are.

For each task: the fit (thresholds, fixed effects, random-effect SDs and correlations,
log-likelihood, convergence), the Wald χ² of the model factor (``car::Anova``, type II), every
pair of models (``emmeans``, Tukey-adjusted), the inferred probability of each answer level per
model and the inferred mean (``emmeans`` ``mode = "prob"``, at random effects 0), the same
model per sentence with random participant intercepts (``y ~ x + (1 | u)``; where that fails,
typically because the participants' variance is 0, as it is for the points of one sentence's
pairwise answers, the fixed-effects ``clm`` of ``y ~ x``), the proportional-odds check
(``nominal_test`` and ``scale_test`` of the ``clm`` of ``y ~ x``) and win/tie/loss counts per
pair, per sentence and in total.

:func:`fit_clmm` fits any clmm formula over a data frame's columns; :func:`analyse_answers`
analyses a study's answers; :func:`write_analysis` writes the folder (JSON, CSV, figures, an
HTML page).
"""

from __future__ import annotations

import html
import io
import json
import math
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd

from vispeech.errors import VispeechError
from vispeech.evaluation.report_parts import (html_figure, html_page, html_table, json_ready, p_text, save_figure,
                                             write_csv)
from vispeech.files import atomic_output_dir, read_text
from vispeech.study.answers import PAIRWISE_ANSWERS, RATINGS, TASKS

INSTALL_R = "apt-get install r-base-core r-cran-ordinal r-cran-car r-cran-emmeans r-cran-jsonlite"
"""The Debian packages the analysis needs."""
SLOPES_FORMULA = "y ~ x + (1 + x | u) + (1 + x | s)"
"""The thesis's model: the model ``x``, random intercepts and slopes per participant ``u`` and sentence ``s``."""
INTERCEPTS_FORMULA = "y ~ x + (1 | u) + (1 | s)"
"""The fallback (and ``random_slopes=False``): random intercepts per participant and sentence."""
SENTENCE_FORMULA = "y ~ x + (1 | u)"
"""The model of one sentence's answers."""
FIXED_FORMULA = "y ~ x"
"""The fixed-effects ``clm``: its nominal and scale effects test the proportional-odds assumption, and
it is a sentence's model when the participants' random intercepts cannot be fitted."""
R_TIMEOUT = 3 * 3600
"""Seconds R may take for one analysis (the thesis's model takes about a minute a task)."""
POINTS = {"win": 2, "tie": 1, "loss": 0}
"""A pairwise answer's points for each of its two models."""
ALL_SENTENCES = "(all)"
"""The ``sentence`` of the win/tie/loss rows that count every sentence."""
ALPHA = 0.05
"""The level at which the proportional-odds check fails."""
REQUIRED_COLUMNS = ("participant", "task", "trial", "sentence", "warmup", "check", "model", "left", "right", "answer")
"""The columns of ``answers.csv`` the analysis reads (the export has more)."""
_TABLES = ("coefficients", "random", "anova", "pairs", "probabilities", "means", "sentences", "wins",
           "proportional_odds")
_FIGURES = ("probabilities", "wins")
ANALYSIS_FILES = ("analysis.json", "report.html",
                  *(f"{task}_{name}.csv" for task in TASKS for name in _TABLES),
                  *(f"{task}_{name}.{kind}" for task in TASKS for name in _FIGURES for kind in ("png", "svg")))
"""What an analysis folder may hold."""


# -- R ------------------------------------------------------------------------------------------


def fit_clmm(frame: pd.DataFrame, formula: str, *, factors: Sequence[str] = (), term: str | None = None,
             fallbacks: Sequence[str] = (), proportional_odds: str | None = None) -> dict:
    """Fit the cumulative-link mixed model ``formula`` (R syntax, logit link, flexible thresholds)
    to ``frame`` with R's ``ordinal::clmm``.

    The response (the formula's left side) becomes an ordered factor: its categories if it is a
    pandas categorical, else its values sorted (numerically if numeric). ``factors`` and every
    non-numeric column become unordered factors (their categories, else their sorted values;
    the first level is the reference); other columns are numbers. ``fallbacks`` are formulas
    tried in turn when a fit fails (an R error, no convergence, no finite standard errors).
    With ``term`` (a factor), its emmeans, Tukey-adjusted pairs, inferred probability of each
    response level and inferred mean (the levels' numbers, or 1, 2, ...) are added; with
    ``proportional_odds`` (a ``clm`` formula) its nominal and scale tests.

    Returns the fit as ``clmm.R`` reports it: ``formula`` (the one fitted, None if none
    could be), ``attempts`` (each formula tried: ``error``, ``warnings``, ``seconds``),
    ``thresholds`` and ``fixed`` (``name``, ``estimate``, ``se``, ``z``, ``p``), ``random``
    (``group``, ``term``, ``variance``, ``sd``), ``correlations``, ``log_lik``, ``aic``,
    ``nobs``, ``groups``, ``convergence`` (optimiser code and message, iterations, max
    gradient, condition number of the Hessian), ``anova`` (Wald χ² per term, type II),
    ``warnings``, and with ``term`` ``emmeans``, ``pairs``, ``probabilities``, ``means``.
    Raises :class:`VispeechError` when R or one of its packages is missing.
    """
    return _run_r([_job("fit", frame, [formula, *fallbacks], factors, term, proportional_odds)])[0][0]


def _job(name: str, frame: pd.DataFrame, formulas: Sequence[str], factors: Sequence[str], term: str | None,
         proportional_odds: str | None) -> tuple[pd.DataFrame, dict]:
    """``frame`` as text and the job ``clmm.R`` runs on it (see its header)."""
    response = formulas[0].partition("~")[0].strip()
    missing = [c for c in (response, *factors, *([term] if term else [])) if c not in frame.columns]
    if missing:
        raise VispeechError(f"the data has no column {missing[0]!r} (columns: {', '.join(map(str, frame.columns))})")
    levels = _levels(frame[response])
    values = ([float(v) for v in levels] if pd.api.types.is_numeric_dtype(frame[response])
              else list(range(1, len(levels) + 1)))
    named = set(factors)
    factor_levels = {c: [_label(v) for v in _levels(frame[c])] for c in frame.columns
                     if c != response and (c in named or not pd.api.types.is_numeric_dtype(frame[c]))}
    text = frame.copy()
    for column in (response, *factor_levels):
        text[column] = frame[column].map(lambda v: "" if pd.isna(v) else _label(v))
    return text, {"id": name, "response": response, "levels": [_label(v) for v in levels], "values": values,
                  "factors": factor_levels, "formulas": list(formulas), "term": term,
                  "proportional_odds": proportional_odds}


def _levels(column: pd.Series) -> list:
    if isinstance(column.dtype, pd.CategoricalDtype):
        return list(column.cat.categories)
    values = column.dropna().unique().tolist()
    return sorted(values) if pd.api.types.is_numeric_dtype(column) else sorted(values, key=str)


def _label(value) -> str:
    """A level as text, whole numbers without a decimal point."""
    if isinstance(value, float | np.floating) and float(value).is_integer():
        return str(int(value))
    return str(value)


def _run_r(jobs: Sequence[tuple[pd.DataFrame, dict]]) -> tuple[list[dict], dict[str, str]]:
    """Run ``clmm.R`` on ``jobs`` (frame, job) in one R process: each job's result, and R's and its
    packages' versions."""
    rscript = shutil.which("Rscript")
    if rscript is None:
        raise VispeechError(f"the study analysis needs R (Rscript was not found): {INSTALL_R}")
    with (tempfile.TemporaryDirectory(prefix="vispeech-clmm-") as tmp,
          resources.as_file(resources.files(__package__).joinpath("clmm.R")) as script):
        folder = Path(tmp)
        specs = []
        for k, (frame, spec) in enumerate(jobs):
            path = folder / f"data{k}.csv"
            frame.to_csv(path, index=False, encoding="utf-8")
            specs.append({**spec, "data": str(path)})
        request, result = folder / "request.json", folder / "result.json"
        request.write_text(json.dumps({"jobs": specs}), encoding="utf-8")
        try:
            done = subprocess.run([rscript, str(script), str(request), str(result)], capture_output=True, text=True,
                                  check=False, timeout=R_TIMEOUT)
        except subprocess.TimeoutExpired:
            raise VispeechError(f"R did not finish the models in {R_TIMEOUT} s (try --no-random-slopes)") from None
        except OSError as exc:
            raise VispeechError(f"cannot run R ({rscript}): {exc.strerror or exc}") from None
        lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
        if done.returncode == 3 and lines and lines[-1].startswith("vispeech-missing-r-packages:"):
            names = lines[-1].partition(":")[2].split()
            raise VispeechError(f"the study analysis needs the R package{'s' if len(names) > 1 else ''} "
                                f"{', '.join(names)}: {INSTALL_R}")
        if done.returncode != 0 or not result.is_file():
            why = next((line for line in reversed(lines) if line.startswith("Error")), lines[-1] if lines else "")
            raise VispeechError(f"R failed (exit code {done.returncode}): {why or 'no message'}")
        answer = json.loads(result.read_text(encoding="utf-8"))
    return answer["jobs"], answer["versions"]


# -- answers ------------------------------------------------------------------------------------


def read_answers(path: str | os.PathLike) -> pd.DataFrame:
    """``answers.csv`` (the study's export), checked by :func:`check_answers`."""
    return check_answers(_read_csv(path, "answers file"), f"answers file {path}", first_line=2)


def read_participants(path: str | os.PathLike) -> pd.DataFrame:
    """``participants.csv``: one row per participant with ``passed_identical`` and
    ``passed_mismatched`` (1, 0 or empty: passed, failed, not shown)."""
    frame = _read_csv(path, "participants file")
    missing = [c for c in ("participant", "passed_identical", "passed_mismatched") if c not in frame.columns]
    if missing:
        raise VispeechError(f"participants file {path} has no column {', '.join(missing)}")
    for column in ("passed_identical", "passed_mismatched"):
        bad = frame.index[~frame[column].isin(["0", "1", ""])]
        if len(bad):
            raise VispeechError(f"participants file {path}, line {bad[0] + 2}: {column} is "
                                f"{frame[column][bad[0]]!r}, not 0, 1 or empty")
    return frame


def _read_csv(path: str | os.PathLike, what: str) -> pd.DataFrame:
    text = read_text(path, what)
    try:
        frame = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeError) as exc:
        raise VispeechError(f"{what} {path} is not a CSV table: {str(exc).strip().splitlines()[-1]}") from None
    return frame.apply(lambda c: c.str.strip())


def check_answers(answers: pd.DataFrame, source: str = "answers", first_line: int | None = None) -> pd.DataFrame:
    """``answers`` checked against the layout of ``answers.csv`` and typed (``trial`` and
    ``warmup`` integers, every other column text); raises :class:`VispeechError` naming
    ``source`` and the first problem's row (0-based), or its line in a file whose first row is on
    line ``first_line``."""
    missing = [c for c in REQUIRED_COLUMNS if c not in answers.columns]
    if missing:
        raise VispeechError(f"{source} has no column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                            f"(an answers.csv from `vispeech study export` has them)")
    if not len(answers):
        raise VispeechError(f"{source} holds no answers")
    frame = answers.reset_index(drop=True).astype({c: str for c in REQUIRED_COLUMNS})

    def refuse(mask: pd.Series | np.ndarray, what: str) -> None:
        mask = np.asarray(mask, dtype=bool)
        if mask.any():
            k = int(np.flatnonzero(mask)[0])
            place = f"row {k}" if first_line is None else f"line {first_line + k}"
            raise VispeechError(f"{source}, {place}: {what.format(**frame.iloc[k].to_dict())}")

    refuse(frame["participant"] == "", "no participant")
    refuse(frame["sentence"] == "", "no sentence")
    refuse(~frame["task"].isin(TASKS), "task {task!r} is neither rating nor pairwise")
    refuse(~frame["trial"].str.fullmatch(r"\d+"), "trial {trial!r} is not a whole number")
    refuse(~frame["warmup"].isin(["0", "1"]), "warmup {warmup!r} is not 0 or 1")
    refuse(~frame["check"].isin(["", "identical", "mismatched"]), "check {check!r} is not empty, identical or "
                                                                  "mismatched")
    rating, pairwise = frame["task"] == "rating", frame["task"] == "pairwise"
    refuse(rating & (frame["model"] == ""), "a rating without a model")
    refuse(rating & ~frame["answer"].isin([str(r) for r in RATINGS]),
           f"rating {{answer!r}} is not a whole number from {RATINGS[0]} to {RATINGS[-1]}")
    refuse(pairwise & ((frame["left"] == "") | (frame["right"] == "")), "a pairwise answer without left and right")
    refuse(pairwise & ~frame["answer"].isin(PAIRWISE_ANSWERS),
           "pairwise answer {answer!r} is not left, tie or right")
    refuse(pairwise & (frame["left"] == frame["right"]) & (frame["check"] == ""),
           "{left!r} on both sides of a pairwise trial that is no check")
    shown = frame[rating & (frame["check"] != "identical")]
    refuse(frame.index.isin(shown.index[shown.duplicated(["participant", "task", "trial", "model"])]),
           "model {model!r} shown twice in trial {trial} of participant {participant!r}")
    return frame.astype({"trial": int, "warmup": int})


@dataclass(frozen=True)
class Exclusions:
    """What was left out of the fits: warm-up and check rows, participants who failed a check."""

    warmup_rows: int
    check_rows: int
    participants: tuple[str, ...] = ()
    checks: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per check (``identical``, ``mismatched``): participants who ``passed``, ``failed``, had ``none``."""


def _exclude(answers: pd.DataFrame, participants: pd.DataFrame | None,
             exclude_failed_checks: bool) -> tuple[pd.DataFrame, Exclusions]:
    checks: dict[str, dict[str, int]] = {}
    failed: set[str] = set()
    if participants is not None:
        for check in ("identical", "mismatched"):
            column = participants[f"passed_{check}"]
            checks[check] = {"passed": int((column == "1").sum()), "failed": int((column == "0").sum()),
                             "none": int((column == "").sum())}
            failed |= set(participants["participant"][column == "0"])
    dropped = tuple(sorted(failed & set(answers["participant"]))) if exclude_failed_checks else ()
    kept = answers[(answers["warmup"] == 0) & (answers["check"] == "") & ~answers["participant"].isin(dropped)]
    return kept, Exclusions(int((answers["warmup"] == 1).sum()), int(((answers["warmup"] == 0)
                                                                      & (answers["check"] != "")).sum()),
                            dropped, checks)


def rating_frame(kept: pd.DataFrame, models: Sequence[str]) -> pd.DataFrame:
    """The ratings of ``kept`` answers (no warm-ups or checks) as the model's frame: ``y``
    (1-9), ``x`` (the model, a categorical over ``models``), ``u`` (participant), ``s``
    (sentence) and ``trial``."""
    rows = kept[kept["task"] == "rating"]
    frame = pd.DataFrame({"y": rows["answer"].astype(int), "x": pd.Categorical(rows["model"], categories=models),
                          "u": rows["participant"], "s": rows["sentence"], "trial": rows["trial"]})
    return frame.reset_index(drop=True)


def points_frame(kept: pd.DataFrame, models: Sequence[str]) -> pd.DataFrame:
    """The pairwise answers of ``kept`` as points (:data:`POINTS`): two rows per answer, one per
    model shown, with ``y`` (0, 1, 2), ``x``, ``u``, ``s`` and ``trial`` as in :func:`rating_frame`."""
    rows = kept[kept["task"] == "pairwise"]
    left = rows["answer"].map({"left": POINTS["win"], "tie": POINTS["tie"], "right": POINTS["loss"]})
    sides = [pd.DataFrame({"y": points, "x": rows[side], "u": rows["participant"], "s": rows["sentence"],
                           "trial": rows["trial"]})
             for side, points in (("left", left), ("right", 2 * POINTS["tie"] - left))]
    frame = pd.concat(sides).sort_index(kind="stable").reset_index(drop=True)
    frame["x"] = pd.Categorical(frame["x"], categories=models)
    return frame


def win_table(frame: pd.DataFrame, models: Sequence[str]) -> pd.DataFrame:
    """Wins, ties and losses of every pair of ``models`` (``a`` before ``b`` in ``models``), per
    sentence and over all (:data:`ALL_SENTENCES`): ``a_wins`` counts the trials (one participant,
    one sentence) where ``a`` scored higher than ``b``. ``frame`` is :func:`rating_frame`'s or
    :func:`points_frame`'s."""
    wide = frame.pivot_table(index=["u", "trial", "s"], columns="x", values="y", aggfunc="first", observed=True)
    sentences = sorted(frame["s"].unique(), key=str)
    rows = []
    for a, b in combinations(models, 2):
        if a not in wide.columns or b not in wide.columns:
            continue
        both = wide[[a, b]].dropna()
        sentence = both.index.get_level_values("s")
        outcome = np.sign(both[a] - both[b])
        for name, mask in [*((s, sentence == s) for s in sentences), (ALL_SENTENCES, np.ones(len(both), bool))]:
            o = outcome[mask]
            rows.append({"sentence": name, "a": a, "b": b, "a_wins": int((o > 0).sum()), "ties": int((o == 0).sum()),
                         "b_wins": int((o < 0).sum())})
    return pd.DataFrame(rows, columns=["sentence", "a", "b", "a_wins", "ties", "b_wins"])


# -- the analysis -------------------------------------------------------------------------------


@dataclass
class TaskAnalysis:
    """One task's analysis (see the module docstring)."""

    task: str
    """``rating`` or ``pairwise``."""
    models: list[str]
    """The models, the reference level first."""
    answers: int
    """Answers fitted (a rating trial gives one per face)."""
    participants: int
    sentences: list[str]
    fit: dict
    """:func:`fit_clmm`'s result for the whole task, with its ``proportional_odds`` tests."""
    sentence_fits: dict[str, dict]
    """Per sentence, :func:`fit_clmm`'s result for :data:`SENTENCE_FORMULA`."""
    wins: pd.DataFrame
    """:func:`win_table`."""

    @property
    def response(self) -> str:
        """What ``y`` is: ``rating`` or ``points``."""
        return "rating" if self.task == "rating" else "points"

    @property
    def wald(self) -> dict | None:
        """The Wald χ² row of the model factor (``chisq``, ``df``, ``p``), if the model was fitted."""
        return next((row for row in self.fit.get("anova", []) if row["term"] == "x"), None)

    @property
    def proportional_odds(self) -> dict:
        """The nominal and scale tests of ``x`` (``df``, ``lrt``, ``p``; p None where the test's
        model could not be fitted) and ``passes``: True when both p ≥ :data:`ALPHA`, False when
        either is below, None when neither is below but one is missing."""
        tests = self.fit.get("proportional_odds") or {}
        nominal = (tests.get("nominal") or {}).get("x")
        scale = (tests.get("scale") or {}).get("x")
        known = [t["p"] for t in (nominal, scale) if t is not None and t["p"] is not None]
        passes = False if any(p < ALPHA for p in known) else True if len(known) == 2 else None
        return {"formula": FIXED_FORMULA, "nominal": nominal, "scale": scale, "passes": passes,
                "error": tests.get("error")}

    @property
    def warnings(self) -> list[str]:
        """What a reader must know: a fallback, R's warnings, failed sentence fits."""
        notes = []
        attempts = self.fit.get("attempts", [])
        for attempt in attempts[:-1] if self.fit.get("formula") else []:
            notes.append(f"{attempt['formula']} failed ({attempt['error']}); fell back to {self.fit['formula']}")
        if not self.fit.get("formula"):
            tried = "; ".join(f"{a['formula']}: {a['error']}" for a in attempts)
            notes.append(f"no model could be fitted ({tried})")
        notes += self.fit.get("warnings", [])
        if self.proportional_odds["error"]:
            notes.append(f"the proportional-odds check failed to run: {self.proportional_odds['error']}")
        simpler = [s for s, fit in self.sentence_fits.items() if fit.get("formula") == FIXED_FORMULA]
        if simpler:
            notes.append(f"sentence{'s' if len(simpler) > 1 else ''} {', '.join(simpler)}: {SENTENCE_FORMULA} "
                         f"failed, {FIXED_FORMULA} fitted instead")
        notes += [f"sentence {s}: no model ({fit['error']})" for s, fit in self.sentence_fits.items()
                  if not fit.get("formula")]
        return notes

    def as_json(self) -> dict:
        return {"task": self.task, "response": self.response, "models": self.models, "answers": self.answers,
                "participants": self.participants, "sentences": self.sentences, "fit": self.fit,
                "wald": self.wald, "proportional_odds": self.proportional_odds,
                "sentence_fits": self.sentence_fits, "wins": self.wins.to_dict("records"),
                "warnings": self.warnings}


@dataclass
class StudyAnalysis:
    """:func:`analyse_answers`'s result: each task's analysis, what was left out, R's versions."""

    tasks: dict[str, TaskAnalysis]
    exclusions: Exclusions
    versions: dict[str, str]
    seconds: float

    def as_json(self) -> dict:
        return json_ready({"tasks": {name: t.as_json() for name, t in self.tasks.items()},
                       "excluded": {"warmup_rows": self.exclusions.warmup_rows,
                                    "check_rows": self.exclusions.check_rows,
                                    "participants": list(self.exclusions.participants)},
                       "checks": self.exclusions.checks, "versions": self.versions, "seconds": self.seconds})

    def summary(self) -> list[str]:
        """A few lines for the terminal: per task the Wald χ² and every pair's Tukey p."""
        e = self.exclusions
        lines = [f"left out: {e.warmup_rows} warm-up rows, {e.check_rows} check rows"
                 + (f", {len(e.participants)} participants who failed a check" if e.participants else "")]
        for t in self.tasks.values():
            lines.append(f"{t.task}: {t.answers} answers by {t.participants} participants on {len(t.sentences)} "
                         f"sentences; models {', '.join(t.models)}")
            if t.wald is not None:
                w = t.wald
                lines.append(f"  {t.fit['formula']}: Wald chi2({w['df']:g}) = {w['chisq']:.2f}, p {_p_text(w['p'])}")
            for pair in t.fit.get("pairs", []):
                lines.append(f"  {pair['a']} - {pair['b']}: {pair['estimate']:+.2f} (SE {pair['se']:.2f}), "
                             f"Tukey p {_p_text(pair['p'])}")
            if t.proportional_odds["nominal"] or t.proportional_odds["scale"]:
                lines.append(f"  proportional odds: {_proportional_odds_text(t.proportional_odds)}")
            lines += [f"  warning: {w}" for w in t.warnings]
        return lines


def _p_text(p: float | None) -> str:
    """A p value after "p" in a line of text: ``= 0.0123``, ``< 0.0001`` or ``n/a``."""
    return "n/a" if p is None else p_text(p) if p < 1e-4 else f"= {p_text(p)}"


def _proportional_odds_text(po: dict) -> str:
    verdict = {True: "holds", False: "violated", None: "not testable"}[po["passes"]]
    nominal, scale = (po["nominal"] or {}).get("p"), (po["scale"] or {}).get("p")
    return f"{verdict} (nominal p {_p_text(nominal)}, scale p {_p_text(scale)})"


def analyse_answers(answers: pd.DataFrame, *, participants: pd.DataFrame | None = None,
                    exclude_failed_checks: bool = False, models: Sequence[str] | None = None,
                    random_slopes: bool = True) -> StudyAnalysis:
    """Analyse a study's answers (``answers.csv``'s layout, see :func:`check_answers`) task by
    task, as the module docstring says, in one R process.

    ``participants`` (``participants.csv``) gives the checks' pass counts, and with
    ``exclude_failed_checks`` the participants who failed one are left out. ``models`` orders
    the models (the first is the reference; default: sorted). ``random_slopes=False`` fits
    :data:`INTERCEPTS_FORMULA` at once (far faster than the thesis's model). Raises
    :class:`VispeechError` for answers that cannot be analysed (nothing left, one model only).
    """
    started = time.perf_counter()
    answers = check_answers(answers)
    if exclude_failed_checks and participants is None:
        raise VispeechError("excluding participants who failed a check needs the participants file")
    kept, exclusions = _exclude(answers, participants, exclude_failed_checks)
    if not len(kept):
        raise VispeechError("no answers are left once warm-ups and checks are left out")
    shown = set(kept["model"][kept["task"] == "rating"]) | set(kept["left"][kept["task"] == "pairwise"]) \
        | set(kept["right"][kept["task"] == "pairwise"])
    if models is None:
        order = sorted(shown)
    else:
        unknown = sorted(shown - set(models))
        if unknown:
            raise VispeechError(f"the answers show model {unknown[0]!r}, which the models given do not name")
        order = list(dict.fromkeys(models))
    frames = {}
    for task in TASKS:
        if not (kept["task"] == task).any():
            continue
        frame = rating_frame(kept, order) if task == "rating" else points_frame(kept, order)
        present = [m for m in order if (frame["x"] == m).any()]
        if len(present) < 2:
            raise VispeechError(f"the {task} answers show one model only ({present[0]}): nothing to compare")
        frame["x"] = frame["x"].cat.set_categories(present)
        frames[task] = frame
    jobs, main_jobs, sentence_jobs = [], {}, {}
    for task, frame in frames.items():
        main_jobs[task] = len(jobs)
        jobs.append(_job(task, frame, [SLOPES_FORMULA, INTERCEPTS_FORMULA] if random_slopes else [INTERCEPTS_FORMULA],
                         ("x", "u", "s"), "x", FIXED_FORMULA))
        for sentence, part in frame.groupby("s", sort=True):
            if part["y"].nunique() > 1 and part["x"].nunique() > 1:
                part = part.assign(x=part["x"].cat.remove_unused_categories())
                sentence_jobs[(task, sentence)] = len(jobs)
                jobs.append(_job(f"{task} {sentence}", part, [SENTENCE_FORMULA, FIXED_FORMULA], ("x", "u", "s"), "x",
                                 None))
    results, versions = _run_r(jobs)
    tasks = {}
    for task, frame in frames.items():
        sentences = sorted(frame["s"].unique(), key=str)
        fits = {s: (results[sentence_jobs[(task, s)]] if (task, s) in sentence_jobs
                    else {"formula": None, "error": "every answer the same, or one model only"})
                for s in sentences}
        present = list(frame["x"].cat.categories)
        tasks[task] = TaskAnalysis(task, present, len(frame) if task == "rating" else len(frame) // 2,
                                   frame["u"].nunique(), sentences, results[main_jobs[task]], fits,
                                   win_table(frame, present))
    return StudyAnalysis(tasks, exclusions, versions, round(time.perf_counter() - started, 2))


# -- the folder ---------------------------------------------------------------------------------


def write_analysis(analysis: StudyAnalysis, out_dir: str | os.PathLike, command: str = "") -> Path:
    """Write ``analysis`` to the folder ``out_dir``, whole or not at all: ``analysis.json``
    (everything), per task (``rating_``, ``pairwise_``) the CSV tables ``coefficients``,
    ``random``, ``anova``, ``pairs``, ``probabilities``, ``means``, ``sentences``, ``wins`` and
    ``proportional_odds``, the figures ``probabilities`` and ``wins`` (PNG and SVG), and
    ``report.html``; ``command`` is shown as how to rebuild it."""
    with atomic_output_dir(out_dir, replaces=ANALYSIS_FILES) as staging:
        (staging / "analysis.json").write_text(json.dumps(analysis.as_json(), indent=2, allow_nan=False) + "\n",
                                               encoding="utf-8")
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
    sentences = [[s, f["formula"], p["a"], p["b"], p["estimate"], p["se"], p["z"], p["p"], ""]
                 for s, f in task.sentence_fits.items() for p in f.get("pairs", [])]
    sentences += [[s, "", "", "", None, None, None, None, f["error"]] for s, f in task.sentence_fits.items()
                  if not f.get("formula")]
    tests = [[kind, "x", t["df"], t["lrt"], t["p"], "yes" if t["p"] is not None and t["p"] >= ALPHA else "no"]
             for kind, t in (("nominal", po["nominal"]), ("scale", po["scale"])) if t]
    return {
        "coefficients": (["kind", "name", "estimate", "se", "z", "p"], coefficients),
        "random": (["group", "term", "variance", "sd"],
                   [[r["group"], r["term"], r["variance"], r["sd"]] for r in fit.get("random", [])]),
        "anova": (["formula", "term", "chisq", "df", "p"],
                  [[fit["formula"], a["term"], a["chisq"], a["df"], a["p"]] for a in fit.get("anova", [])]),
        "pairs": (["a", "b", "estimate", "se", "z", "p_tukey"],
                  [[p["a"], p["b"], p["estimate"], p["se"], p["z"], p["p"]] for p in fit.get("pairs", [])]),
        "probabilities": (["model", task.response, "probability", "se", "lower", "upper"],
                          [[p["level"], p["response"], p["probability"], p["se"], p["lower"], p["upper"]]
                           for p in fit.get("probabilities", [])]),
        "means": (["model", "mean", "se", "lower", "upper"],
                  [[m["level"], m["mean"], m["se"], m["lower"], m["upper"]] for m in fit.get("means", [])]),
        "sentences": (["sentence", "formula", "a", "b", "estimate", "se", "z", "p_tukey", "error"], sentences),
        "wins": (list(task.wins.columns), task.wins.values.tolist()),
        "proportional_odds": (["test", "term", "df", "lrt", "p", "passes"], tests),
    }


def _figures(task: TaskAnalysis, folder: Path) -> list[tuple[str, str]]:
    """Draw ``task``'s figures into ``folder`` (PNG and SVG); (file stem, caption) of each."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    drawn = []
    probabilities = task.fit.get("probabilities", [])
    if probabilities:
        levels = list(dict.fromkeys(p["response"] for p in probabilities))
        figure = Figure(figsize=(max(6.0, 0.75 * len(levels) + 3.5), 4.2), dpi=100)
        FigureCanvasAgg(figure)
        axes = figure.add_subplot()
        width = 0.7 / len(task.models)
        for i, model in enumerate(task.models):
            rows = [next(p for p in probabilities if p["level"] == model and p["response"] == level)
                    for level in levels]
            x = np.arange(len(levels)) + (i - (len(task.models) - 1) / 2) * width
            y = np.array([r["probability"] for r in rows], dtype=float)
            low = np.clip([np.nan if r["lower"] is None else r["lower"] for r in rows], 0, 1)
            high = np.clip([np.nan if r["upper"] is None else r["upper"] for r in rows], 0, 1)
            axes.errorbar(x, y, yerr=[y - low, high - y], marker="o", markersize=4, linewidth=1, capsize=3,
                          label=model)
        axes.set_xticks(np.arange(len(levels)), levels)
        axes.set_xlabel(task.response)
        axes.set_ylabel("inferred probability (95 % CI)")
        axes.set_ylim(bottom=0)
        axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="model")
        axes.set_title(f"{task.task}: {task.fit['formula']}", fontsize=9)
        figure.tight_layout()
        save_figure(figure, folder / f"{task.task}_probabilities")
        caption = (f"{task.task}: the inferred probability of each {task.response} per model, with 95 % "
                   "confidence intervals (at random effects 0)")
        drawn.append((f"{task.task}_probabilities", caption))
    pairs = task.wins[["a", "b"]].drop_duplicates().values.tolist()
    if pairs:
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
            for column, label, colour in (("a_wins", f"{a} better", "tab:blue"), ("ties", "tie", "0.75"),
                                          ("b_wins", f"{b} better", "tab:orange")):
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
            axes.legend(fontsize=7, ncol=3, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False,
                        handlelength=1.2, columnspacing=1.0)
        figure.tight_layout()
        save_figure(figure, folder / f"{task.task}_wins")
        caption = (f"{task.task}: wins, ties and losses of each pair of models per sentence and over all "
                   f"({'higher rating' if task.task == 'rating' else 'preferred'} in one trial)")
        drawn.append((f"{task.task}_wins", caption))
    return drawn


def _html_table(header: Sequence[str], rows: list[list]) -> str:
    """:func:`~vispeech.evaluation.report_parts.html_table` of rows whose missing numbers are None."""
    return html_table(header, [[math.nan if v is None else v for v in row] for row in rows])


def _html_p(p: float | None) -> str:
    return "–" if p is None else p_text(p)


def _html(analysis: StudyAnalysis, figures: list[tuple[str, str]], command: str) -> str:
    e = analysis.exclusions
    parts = ["<h1>Perceptual study analysis</h1>",
             f"<p>Left out of the fits: {e.warmup_rows} warm-up rows, {e.check_rows} check rows"
             + (f", the {len(e.participants)} participants who failed a check" if e.participants else "")
             + f". R {html.escape(analysis.versions.get('R', '?'))}, ordinal "
             f"{html.escape(analysis.versions.get('ordinal', '?'))}, "
             f"car {html.escape(analysis.versions.get('car', '?'))}"
             f", emmeans {html.escape(analysis.versions.get('emmeans', '?'))}.</p>"]
    if command:
        parts.append(f"<p>Rebuild with: <code>{html.escape(command)}</code></p>")
    if e.checks:
        parts.append(_html_table(["check", "passed", "failed", "not shown"],
                                 [[name, c["passed"], c["failed"], c["none"]] for name, c in e.checks.items()]))
    for t in analysis.tasks.values():
        fit = t.fit
        parts.append(f"<h2>{html.escape(t.task)}: {t.answers} answers by {t.participants} participants on "
                     f"{len(t.sentences)} sentences</h2>")
        if t.task == "pairwise":
            parts.append("<p>Each answer gives each of its two models points: win 2, tie 1, loss 0.</p>")
        parts += [f"<p class='warning'>{html.escape(w)}</p>" for w in t.warnings]
        if fit.get("formula"):
            c = fit["convergence"]
            parts.append(f"<p>Cumulative-link mixed model <code>{html.escape(fit['formula'])}</code> "
                         f"(y: {t.response}, x: model, u: participant, s: sentence; ordinal::clmm, logit link): "
                         f"{fit['nobs']:g} observations, log-likelihood {fit['log_lik']:.2f}, optimiser "
                         f"{html.escape(str(c['message']))}, max |gradient| {c['max_grad']:.2g}, condition number of "
                         f"the Hessian {c['cond_h']:.3g}.</p>")
            w = t.wald
            if w is not None:
                parts.append(f"<p><b>Do the models differ?</b> Wald χ²({w['df']:g}) = {w['chisq']:.2f}, "
                             f"p {html.escape(_p_text(w['p']))} (car::Anova, type II).</p>")
            parts.append("<p>Pairs (emmeans, Tukey-adjusted; estimate: a − b on the latent logit scale, positive "
                         f"when a gets higher {t.response}):</p>")
            parts.append(_html_table(["a", "b", "estimate", "SE", "z", "p (Tukey)"],
                                     [[p["a"], p["b"], p["estimate"], p["se"], p["z"], _html_p(p["p"])]
                                      for p in fit.get("pairs", [])]))
            parts.append(f"<p>Inferred mean {t.response} per model (95 % CI):</p>")
            parts.append(_html_table(["model", "mean", "SE", "lower", "upper"],
                                     [[m["level"], m["mean"], m["se"], m["lower"], m["upper"]]
                                      for m in fit.get("means", [])]))
            parts.append("<p>Coefficients (thresholds θ: logit P(y ≤ k) = θ<sub>k</sub> − x's effect):</p>")
            parts.append(_html_table(["kind", "name", "estimate", "SE", "z", "p"],
                                     [[r[0], r[1], r[2], r[3], r[4], _html_p(r[5]) if r[5] != "" else ""]
                                      for r in _tables(t)["coefficients"][1]]))
            parts.append(_html_table(["group", "term", "variance", "SD"],
                                     [[r["group"], r["term"], r["variance"], r["sd"]] for r in fit.get("random", [])]))
            if fit.get("correlations"):
                parts.append(_html_table(["group", "a", "b", "correlation"],
                                         [[r["group"], r["a"], r["b"], r["r"]] for r in fit["correlations"]]))
        if t.proportional_odds["nominal"] or t.proportional_odds["scale"]:
            parts.append(f"<p>Proportional odds (nominal_test and scale_test of the clm of <code>{FIXED_FORMULA}"
                         f"</code>): {html.escape(_proportional_odds_text(t.proportional_odds))}.</p>")
        per_sentence = [[s, f["formula"], p["a"], p["b"], p["estimate"], _html_p(p["p"])]
                        for s, f in t.sentence_fits.items() for p in f.get("pairs", [])]
        if per_sentence:
            parts.append(f"<p>Per sentence (<code>{SENTENCE_FORMULA}</code>, or <code>{FIXED_FORMULA}</code> where "
                         "that cannot be fitted):</p>")
            parts.append(_html_table(["sentence", "model", "a", "b", "estimate", "p (Tukey)"], per_sentence))
        parts.append("<p>Wins, ties and losses (a wins: a scored higher than b in one trial):</p>")
        parts.append(_html_table(list(t.wins.columns), t.wins.values.tolist()))
        parts += [html_figure(stem, caption) for stem, caption in figures if stem.startswith(f"{t.task}_")]
    return html_page("vispeech study analysis", parts)
