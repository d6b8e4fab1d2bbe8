"""Cumulative-link mixed models through R (``ordinal::clmm``, ``car::Anova``, ``emmeans``):
:func:`fit_clmm` fits any formula to a data frame; :func:`clmm_job` and :func:`run_clmm` let the
study analysis (:mod:`vispeech.study.analysis`) send all its fits to one R process, which runs
``clmm.R``."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from vispeech.errors import VispeechError

INSTALL_R = "apt-get install r-base-core r-cran-ordinal r-cran-car r-cran-emmeans r-cran-jsonlite"
"""The Debian packages the analysis needs."""
R_TIMEOUT = 3 * 3600
"""Seconds R may take for one analysis (the thesis's model takes about a minute a task)."""


def fit_clmm(
    frame: pd.DataFrame,
    formula: str,
    *,
    factors: Sequence[str] = (),
    term: str | None = None,
    fallbacks: Sequence[str] = (),
    proportional_odds: str | None = None,
) -> dict:
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
    return run_clmm([clmm_job("fit", frame, [formula, *fallbacks], factors, term, proportional_odds)])[0][0]


def clmm_job(
    name: str,
    frame: pd.DataFrame,
    formulas: Sequence[str],
    factors: Sequence[str],
    term: str | None,
    proportional_odds: str | None,
) -> tuple[pd.DataFrame, dict]:
    """``frame`` as text and the job ``clmm.R`` runs on it (see its header)."""
    response = formulas[0].partition("~")[0].strip()
    missing = [c for c in (response, *factors, *([term] if term else [])) if c not in frame.columns]
    if missing:
        raise VispeechError(f"the data has no column {missing[0]!r} (columns: {', '.join(map(str, frame.columns))})")
    levels = _levels(frame[response])
    values = (
        [float(v) for v in levels]
        if pd.api.types.is_numeric_dtype(frame[response])
        else list(range(1, len(levels) + 1))
    )
    named = set(factors)
    factor_levels = {
        c: [_label(v) for v in _levels(frame[c])]
        for c in frame.columns
        if c != response and (c in named or not pd.api.types.is_numeric_dtype(frame[c]))
    }
    text = frame.copy()
    for column in (response, *factor_levels):
        text[column] = frame[column].map(lambda v: "" if pd.isna(v) else _label(v))
    return text, {
        "id": name,
        "response": response,
        "levels": [_label(v) for v in levels],
        "values": values,
        "factors": factor_levels,
        "formulas": list(formulas),
        "term": term,
        "proportional_odds": proportional_odds,
    }


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


def run_clmm(jobs: Sequence[tuple[pd.DataFrame, dict]]) -> tuple[list[dict], dict[str, str]]:
    """Run ``clmm.R`` on ``jobs`` (frame, job) in one R process: each job's result, and R's and its
    packages' versions."""
    rscript = shutil.which("Rscript")
    if rscript is None:
        raise VispeechError(f"the study analysis needs R (Rscript was not found): {INSTALL_R}")
    with (
        tempfile.TemporaryDirectory(prefix="vispeech-clmm-") as tmp,
        resources.as_file(resources.files(__package__).joinpath("clmm.R")) as script,
    ):
        folder = Path(tmp)
        specs = []
        for k, (frame, spec) in enumerate(jobs):
            path = folder / f"data{k}.csv"
            frame.to_csv(path, index=False, encoding="utf-8")
            specs.append({**spec, "data": str(path)})
        request, result = folder / "request.json", folder / "result.json"
        request.write_text(json.dumps({"jobs": specs}), encoding="utf-8")
        try:
            done = subprocess.run(
                [rscript, str(script), str(request), str(result)],
                capture_output=True,
                text=True,
                check=False,
                timeout=R_TIMEOUT,
            )
        except subprocess.TimeoutExpired:
            raise VispeechError(f"R did not finish the models in {R_TIMEOUT} s (try --no-random-slopes)") from None
        except OSError as exc:
            raise VispeechError(f"cannot run R ({rscript}): {exc.strerror or exc}") from None
        lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
        if done.returncode == 3 and lines and lines[-1].startswith("vispeech-missing-r-packages:"):
            names = lines[-1].partition(":")[2].split()
            raise VispeechError(
                f"the study analysis needs the R package{'s' if len(names) > 1 else ''} {', '.join(names)}: {INSTALL_R}"
            )
        if done.returncode != 0 or not result.is_file():
            why = next((line for line in reversed(lines) if line.startswith("Error")), lines[-1] if lines else "")
            raise VispeechError(f"R failed (exit code {done.returncode}): {why or 'no message'}")
        answer = json.loads(result.read_text(encoding="utf-8"))
    return answer["jobs"], answer["versions"]
