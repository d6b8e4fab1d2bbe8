"""Comparing models over utterances: the repeated-measures ANOVA and the pairwise tests."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require_module
from vispeech import VispeechError

require_module("statsmodels", "statsmodels (the train extra)")

from vispeech.evaluation.statistics import compare_models  # noqa: E402


def scores(effect: float, seed: int, n: int = 40) -> dict[str, np.ndarray]:
    """Three models on ``n`` utterances: utterance difficulty shared, model c ``effect`` worse."""
    rng = np.random.default_rng(seed)
    difficulty = rng.normal(10, 3, n)
    return {name: difficulty + shift + rng.normal(0, 1, n) for name, shift in (("a", 0.0), ("b", 0.0), ("c", effect))}


def test_a_planted_effect_is_found_and_located():
    result = compare_models(scores(1.5, 0), "rmse")
    assert result.anova.p < 1e-6 and result.anova.df_model == 2 and result.anova.df_error == 78
    pairs = {(p.a, p.b): p for p in result.pairs}
    assert pairs[("a", "b")].p_tukey > 0.05 and pairs[("a", "c")].p_tukey < 1e-4 and pairs[("b", "c")].p_tukey < 1e-4
    assert pairs[("a", "c")].difference == pytest.approx(-1.5, abs=0.6)
    assert pairs[("a", "c")].d_z < -0.5  # at least a medium effect
    assert pairs[("a", "c")].p_lsd <= pairs[("a", "c")].p_tukey  # Tukey corrects for the three comparisons


def test_no_planted_effect_is_rarely_found():
    """Under the null the ANOVA's p is uniform: about 5 % of seeds fall below 0.05."""
    found = sum(compare_models(scores(0.0, seed)).anova.p < 0.05 for seed in range(60))
    assert found <= 8


def test_the_anova_and_lsd_agree_with_their_textbook_forms():
    from scipy import stats

    data = scores(0.7, 3, n=25)
    result = compare_models(data)
    matrix = np.column_stack(list(data.values()))
    n, k = matrix.shape
    grand = matrix.mean()
    ss_model = n * ((matrix.mean(axis=0) - grand) ** 2).sum()
    ss_subject = k * ((matrix.mean(axis=1) - grand) ** 2).sum()
    ss_error = ((matrix - grand) ** 2).sum() - ss_model - ss_subject
    f = (ss_model / (k - 1)) / (ss_error / ((k - 1) * (n - 1)))
    assert result.anova.f == pytest.approx(f, rel=1e-9)
    assert result.anova.partial_eta_squared == pytest.approx(ss_model / (ss_model + ss_error), rel=1e-9)
    two = compare_models({"a": data["a"], "c": data["c"]})
    assert two.pairs[0].p_lsd == pytest.approx(stats.ttest_rel(data["a"], data["c"]).pvalue, rel=1e-9)
    assert two.pairs[0].p_tukey == pytest.approx(two.pairs[0].p_lsd, rel=1e-4)  # two models: the same test


def test_too_little_to_compare():
    with pytest.raises(VispeechError, match="two of them"):
        compare_models({"a": np.ones(5)})
    with pytest.raises(VispeechError, match="three utterances"):
        compare_models({"a": np.array([1.0, 2.0, np.nan]), "b": np.array([1.0, 3.0, 2.0])})
