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

:func:`vispeech.study.clmm.fit_clmm` fits any clmm formula over a data frame's columns;
:func:`analyse_answers` analyses a study's answers; :func:`vispeech.study.report_folder.write_analysis`
writes the folder (JSON, CSV, figures, an HTML page).
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
import pandas as pd

from vispeech.errors import VispeechError
from vispeech.evaluation.report_parts import json_ready, p_text
from vispeech.files import read_text
from vispeech.study.answers import PAIRWISE_ANSWERS, RATINGS, TASKS
from vispeech.study.clmm import clmm_job, run_clmm

SLOPES_FORMULA = "y ~ x + (1 + x | u) + (1 + x | s)"
"""The thesis's model: the model ``x``, random intercepts and slopes per participant ``u`` and sentence ``s``."""
INTERCEPTS_FORMULA = "y ~ x + (1 | u) + (1 | s)"
"""The fallback (and ``random_slopes=False``): random intercepts per participant and sentence."""
SENTENCE_FORMULA = "y ~ x + (1 | u)"
"""The model of one sentence's answers."""
FIXED_FORMULA = "y ~ x"
"""The fixed-effects ``clm``: its nominal and scale effects test the proportional-odds assumption, and
it is a sentence's model when the participants' random intercepts cannot be fitted."""
POINTS = {"win": 2, "tie": 1, "loss": 0}
"""A pairwise answer's points for each of its two models."""
ALL_SENTENCES = "(all)"
"""The ``sentence`` of the win/tie/loss rows that count every sentence."""
ALPHA = 0.05
"""The level at which the proportional-odds check fails."""
REQUIRED_COLUMNS = ("participant", "task", "trial", "sentence", "warmup", "check", "model", "left", "right", "answer")
"""The columns of ``answers.csv`` the analysis reads (the export has more)."""


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
            raise VispeechError(
                f"participants file {path}, line {bad[0] + 2}: {column} is {frame[column][bad[0]]!r}, not 0, 1 or empty"
            )
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
        raise VispeechError(
            f"{source} has no column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
            f"(an answers.csv from `vispeech study export` has them)"
        )
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
    refuse(
        ~frame["check"].isin(["", "identical", "mismatched"]), "check {check!r} is not empty, identical or mismatched"
    )
    rating, pairwise = frame["task"] == "rating", frame["task"] == "pairwise"
    refuse(rating & (frame["model"] == ""), "a rating without a model")
    refuse(
        rating & ~frame["answer"].isin([str(r) for r in RATINGS]),
        f"rating {{answer!r}} is not a whole number from {RATINGS[0]} to {RATINGS[-1]}",
    )
    refuse(pairwise & ((frame["left"] == "") | (frame["right"] == "")), "a pairwise answer without left and right")
    refuse(pairwise & ~frame["answer"].isin(PAIRWISE_ANSWERS), "pairwise answer {answer!r} is not left, tie or right")
    refuse(
        pairwise & (frame["left"] == frame["right"]) & (frame["check"] == ""),
        "{left!r} on both sides of a pairwise trial that is no check",
    )
    shown = frame[rating & (frame["check"] != "identical")]
    refuse(
        frame.index.isin(shown.index[shown.duplicated(["participant", "task", "trial", "model"])]),
        "model {model!r} shown twice in trial {trial} of participant {participant!r}",
    )
    return frame.astype({"trial": int, "warmup": int})


@dataclass(frozen=True)
class Exclusions:
    """What was left out of the fits: warm-up and check rows, participants who failed a check."""

    warmup_rows: int
    check_rows: int
    participants: tuple[str, ...] = ()
    checks: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per check (``identical``, ``mismatched``): participants who ``passed``, ``failed``, had ``none``."""


def _exclude(
    answers: pd.DataFrame, participants: pd.DataFrame | None, exclude_failed_checks: bool
) -> tuple[pd.DataFrame, Exclusions]:
    checks: dict[str, dict[str, int]] = {}
    failed: set[str] = set()
    if participants is not None:
        for check in ("identical", "mismatched"):
            column = participants[f"passed_{check}"]
            checks[check] = {
                "passed": int((column == "1").sum()),
                "failed": int((column == "0").sum()),
                "none": int((column == "").sum()),
            }
            failed |= set(participants["participant"][column == "0"])
    dropped = tuple(sorted(failed & set(answers["participant"]))) if exclude_failed_checks else ()
    kept = answers[(answers["warmup"] == 0) & (answers["check"] == "") & ~answers["participant"].isin(dropped)]
    return kept, Exclusions(
        int((answers["warmup"] == 1).sum()),
        int(((answers["warmup"] == 0) & (answers["check"] != "")).sum()),
        dropped,
        checks,
    )


def rating_frame(kept: pd.DataFrame, models: Sequence[str]) -> pd.DataFrame:
    """The ratings of ``kept`` answers (no warm-ups or checks) as the model's frame: ``y``
    (1-9), ``x`` (the model, a categorical over ``models``), ``u`` (participant), ``s``
    (sentence) and ``trial``."""
    rows = kept[kept["task"] == "rating"]
    frame = pd.DataFrame(
        {
            "y": rows["answer"].astype(int),
            "x": pd.Categorical(rows["model"], categories=models),
            "u": rows["participant"],
            "s": rows["sentence"],
            "trial": rows["trial"],
        }
    )
    return frame.reset_index(drop=True)


def points_frame(kept: pd.DataFrame, models: Sequence[str]) -> pd.DataFrame:
    """The pairwise answers of ``kept`` as points (:data:`POINTS`): two rows per answer, one per
    model shown, with ``y`` (0, 1, 2), ``x``, ``u``, ``s`` and ``trial`` as in :func:`rating_frame`."""
    rows = kept[kept["task"] == "pairwise"]
    left = rows["answer"].map({"left": POINTS["win"], "tie": POINTS["tie"], "right": POINTS["loss"]})
    sides = [
        pd.DataFrame(
            {"y": points, "x": rows[side], "u": rows["participant"], "s": rows["sentence"], "trial": rows["trial"]}
        )
        for side, points in (("left", left), ("right", 2 * POINTS["tie"] - left))
    ]
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
            rows.append(
                {
                    "sentence": name,
                    "a": a,
                    "b": b,
                    "a_wins": int((o > 0).sum()),
                    "ties": int((o == 0).sum()),
                    "b_wins": int((o < 0).sum()),
                }
            )
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
    """:func:`~vispeech.study.clmm.fit_clmm`'s result for the whole task, with its ``proportional_odds`` tests."""
    sentence_fits: dict[str, dict]
    """Per sentence, :func:`~vispeech.study.clmm.fit_clmm`'s result for :data:`SENTENCE_FORMULA`."""
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
        return {
            "formula": FIXED_FORMULA,
            "nominal": nominal,
            "scale": scale,
            "passes": passes,
            "error": tests.get("error"),
        }

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
            notes.append(
                f"sentence{'s' if len(simpler) > 1 else ''} {', '.join(simpler)}: {SENTENCE_FORMULA} "
                f"failed, {FIXED_FORMULA} fitted instead"
            )
        notes += [
            f"sentence {s}: no model ({fit['error']})"
            for s, fit in self.sentence_fits.items()
            if not fit.get("formula")
        ]
        return notes

    def as_json(self) -> dict:
        return {
            "task": self.task,
            "response": self.response,
            "models": self.models,
            "answers": self.answers,
            "participants": self.participants,
            "sentences": self.sentences,
            "fit": self.fit,
            "wald": self.wald,
            "proportional_odds": self.proportional_odds,
            "sentence_fits": self.sentence_fits,
            "wins": self.wins.to_dict("records"),
            "warnings": self.warnings,
        }


@dataclass
class StudyAnalysis:
    """:func:`analyse_answers`'s result: each task's analysis, what was left out, R's versions."""

    tasks: dict[str, TaskAnalysis]
    exclusions: Exclusions
    versions: dict[str, str]
    seconds: float

    def as_json(self) -> dict:
        return json_ready(
            {
                "tasks": {name: t.as_json() for name, t in self.tasks.items()},
                "excluded": {
                    "warmup_rows": self.exclusions.warmup_rows,
                    "check_rows": self.exclusions.check_rows,
                    "participants": list(self.exclusions.participants),
                },
                "checks": self.exclusions.checks,
                "versions": self.versions,
                "seconds": self.seconds,
            }
        )

    def summary(self) -> list[str]:
        """A few lines for the terminal: per task the Wald χ² and every pair's Tukey p."""
        e = self.exclusions
        lines = [
            f"left out: {e.warmup_rows} warm-up rows, {e.check_rows} check rows"
            + (f", {len(e.participants)} participants who failed a check" if e.participants else "")
        ]
        for t in self.tasks.values():
            lines.append(
                f"{t.task}: {t.answers} answers by {t.participants} participants on {len(t.sentences)} "
                f"sentences; models {', '.join(t.models)}"
            )
            if t.wald is not None:
                w = t.wald
                lines.append(f"  {t.fit['formula']}: Wald chi2({w['df']:g}) = {w['chisq']:.2f}, p {p_phrase(w['p'])}")
            for pair in t.fit.get("pairs", []):
                lines.append(
                    f"  {pair['a']} - {pair['b']}: {pair['estimate']:+.2f} (SE {pair['se']:.2f}), "
                    f"Tukey p {p_phrase(pair['p'])}"
                )
            if t.proportional_odds["nominal"] or t.proportional_odds["scale"]:
                lines.append(f"  proportional odds: {proportional_odds_phrase(t.proportional_odds)}")
            lines += [f"  warning: {w}" for w in t.warnings]
        return lines


def p_phrase(p: float | None) -> str:
    """A p value after "p" in a line of text: ``= 0.0123``, ``< 0.0001`` or ``n/a``."""
    return "n/a" if p is None else p_text(p) if p < 1e-4 else f"= {p_text(p)}"


def proportional_odds_phrase(po: dict) -> str:
    """:attr:`TaskAnalysis.proportional_odds` in words: its verdict and both tests' p."""
    verdict = {True: "holds", False: "violated", None: "not testable"}[po["passes"]]
    nominal, scale = (po["nominal"] or {}).get("p"), (po["scale"] or {}).get("p")
    return f"{verdict} (nominal p {p_phrase(nominal)}, scale p {p_phrase(scale)})"


def analyse_answers(
    answers: pd.DataFrame,
    *,
    participants: pd.DataFrame | None = None,
    exclude_failed_checks: bool = False,
    models: Sequence[str] | None = None,
    random_slopes: bool = True,
) -> StudyAnalysis:
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
    frames = _task_frames(kept, _model_order(kept, models))
    planned = {task: _task_jobs(task, frame, random_slopes) for task, frame in frames.items()}
    results, versions = run_clmm([job for jobs in planned.values() for job in jobs.values()])
    fits = dict(zip([(task, key) for task, jobs in planned.items() for key in jobs], results))
    tasks = {task: _task_analysis(task, frame, fits) for task, frame in frames.items()}
    return StudyAnalysis(tasks, exclusions, versions, round(time.perf_counter() - started, 2))


def _model_order(kept: pd.DataFrame, models: Sequence[str] | None) -> list[str]:
    """The models in order: ``models`` (which must name every model ``kept`` shows), else the
    models shown, sorted."""
    shown = (
        set(kept["model"][kept["task"] == "rating"])
        | set(kept["left"][kept["task"] == "pairwise"])
        | set(kept["right"][kept["task"] == "pairwise"])
    )
    if models is None:
        return sorted(shown)
    unknown = sorted(shown - set(models))
    if unknown:
        raise VispeechError(f"the answers show model {unknown[0]!r}, which the models given do not name")
    return list(dict.fromkeys(models))


def _task_frames(kept: pd.DataFrame, order: list[str]) -> dict[str, pd.DataFrame]:
    """The model's frame of each task answered (:func:`rating_frame`, :func:`points_frame`), ``x``
    over the models the task shows; raises :class:`VispeechError` for a task that shows one."""
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
    return frames


def _task_jobs(task: str, frame: pd.DataFrame, random_slopes: bool) -> dict[str | None, tuple[pd.DataFrame, dict]]:
    """The fits of one task for :func:`run_clmm`: the whole task's (key None), then each sentence's
    whose answers differ and show two models or more (key: the sentence)."""
    jobs: dict[str | None, tuple[pd.DataFrame, dict]] = {
        None: clmm_job(
            task,
            frame,
            [SLOPES_FORMULA, INTERCEPTS_FORMULA] if random_slopes else [INTERCEPTS_FORMULA],
            ("x", "u", "s"),
            "x",
            FIXED_FORMULA,
        )
    }
    for sentence, part in frame.groupby("s", sort=True):
        if part["y"].nunique() > 1 and part["x"].nunique() > 1:
            part = part.assign(x=part["x"].cat.remove_unused_categories())
            jobs[str(sentence)] = clmm_job(
                f"{task} {sentence}", part, [SENTENCE_FORMULA, FIXED_FORMULA], ("x", "u", "s"), "x", None
            )
    return jobs


def _task_analysis(task: str, frame: pd.DataFrame, fits: dict[tuple[str, str | None], dict]) -> TaskAnalysis:
    """One task's analysis from R's ``fits`` (keyed as :func:`_task_jobs`'s jobs, with the task)."""
    sentences = sorted(frame["s"].unique(), key=str)
    sentence_fits = {
        s: fits[(task, s)]
        if (task, s) in fits
        else {"formula": None, "error": "every answer the same, or one model only"}
        for s in sentences
    }
    present = list(frame["x"].cat.categories)
    return TaskAnalysis(
        task,
        present,
        len(frame) if task == "rating" else len(frame) // 2,
        frame["u"].nunique(),
        sentences,
        fits[(task, None)],
        sentence_fits,
        win_table(frame, present),
    )
