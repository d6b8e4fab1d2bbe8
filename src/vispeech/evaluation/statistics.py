"""Do the models differ? Repeated-measures ANOVA over utterances and pairwise comparisons.

The seeds judge models this way (Beskow 2004: per-sentence errors of every model, a
repeated-measures ANOVA with the model as the within-sentence factor, pairwise comparisons
by Fisher's LSD). :func:`compare_models` takes one score per utterance and model (the same
utterances for every model):

- the ANOVA by statsmodels (``AnovaRM``): F, degrees of freedom, p, and the partial η² of the
  model factor (its sum of squares over itself plus the error's);
- every pair of models: the mean difference, Fisher's LSD (a t test on the difference with the
  ANOVA's error mean square, ``t = d / sqrt(2 MSE / n)``, its degrees of freedom) and Tukey's
  HSD from the same error term (``q = |d| / sqrt(MSE / n)`` against the studentized range of
  k models, scipy), and Cohen's d_z (the mean paired difference over its standard deviation).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from vispeech.errors import VispeechError


@dataclass(frozen=True)
class Anova:
    """The repeated-measures ANOVA of one score: the model factor's F, degrees of freedom, p,
    partial η², and the error mean square the pairwise tests use."""

    score: str
    f: float
    df_model: int
    df_error: int
    p: float
    partial_eta_squared: float
    mse: float
    utterances: int


@dataclass(frozen=True)
class PairComparison:
    """Models ``a`` and ``b``: ``difference`` (mean of a − b), Fisher's LSD ``t`` and ``p_lsd``,
    Tukey's ``p_tukey``, and Cohen's ``d_z``."""

    a: str
    b: str
    difference: float
    t: float
    p_lsd: float
    p_tukey: float
    d_z: float


@dataclass(frozen=True)
class Comparison:
    """:func:`compare_models`'s result: the means per model, the ANOVA and every pair."""

    means: dict[str, float]
    anova: Anova
    pairs: list[PairComparison]


def compare_models(scores: Mapping[str, np.ndarray], score: str = "score") -> Comparison:
    """Compare models by per-utterance ``scores`` (model → one value per utterance, the same
    utterances in the same order; ``score`` names them). Utterances where any model's value is
    not finite are left out. Raises :class:`VispeechError` with fewer than two models or three
    utterances."""
    import pandas as pd
    from scipy import stats
    from statsmodels.stats.anova import AnovaRM

    labels = list(scores)
    if len(labels) < 2:
        raise VispeechError("comparing models needs two of them at least")
    matrix = np.column_stack([np.asarray(scores[label], dtype=float) for label in labels])
    matrix = matrix[np.isfinite(matrix).all(axis=1)]
    n, k = matrix.shape
    if n < 3:
        raise VispeechError(f"comparing models needs three utterances at least, got {n}")
    frame = pd.DataFrame(
        {"utterance": np.repeat(np.arange(n), k), "model": np.tile(np.arange(k), n), "value": matrix.reshape(-1)}
    )
    table = AnovaRM(frame, "value", "utterance", within=["model"]).fit().anova_table
    f, df_model, df_error, p = (float(table.iloc[0][c]) for c in ("F Value", "Num DF", "Den DF", "Pr > F"))
    grand = matrix.mean()
    ss_model = n * float(((matrix.mean(axis=0) - grand) ** 2).sum())
    residual = matrix - matrix.mean(axis=0) - matrix.mean(axis=1, keepdims=True) + grand
    ss_error = float((residual**2).sum())
    mse = ss_error / df_error
    anova = Anova(score, f, int(df_model), int(df_error), p, ss_model / (ss_model + ss_error), mse, n)
    pairs = []
    for i, j in combinations(range(k), 2):
        diff = matrix[:, i] - matrix[:, j]
        d = float(diff.mean())
        t = d / np.sqrt(2 * mse / n) if mse > 0 else float("inf") * np.sign(d)
        p_lsd = float(2 * stats.t.sf(abs(t), df_error))
        q = abs(d) / np.sqrt(mse / n) if mse > 0 else float("inf")
        p_tukey = float(stats.studentized_range.sf(q, k, df_error))
        spread = float(diff.std(ddof=1))
        pairs.append(
            PairComparison(
                labels[i], labels[j], d, float(t), p_lsd, p_tukey, d / spread if spread > 0 else float("nan")
            )
        )
    return Comparison({label: float(matrix[:, i].mean()) for i, label in enumerate(labels)}, anova, pairs)
