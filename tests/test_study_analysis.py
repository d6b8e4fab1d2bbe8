"""``vispeech study analyse``: cumulative-link mixed models through R's ordinal, car and emmeans.

The wrapper gives the ordinal package's own published numbers on its ``wine`` data; the thesis's
model ``y ~ x + (1 + x | u) + (1 + x | s)`` finds an effect planted in simulated ratings and
none where none was planted; the pairwise coding and the win tables are counted by hand.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from functools import cache

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from conftest import require
from scipy.special import expit, logit

from vispeech.cli import main
from vispeech.errors import VispeechError
from vispeech.study import analysis
from vispeech.study.analysis import (
    ALL_SENTENCES,
    INTERCEPTS_FORMULA,
    SENTENCE_FORMULA,
    SLOPES_FORMULA,
    analyse_answers,
    points_frame,
    win_table,
)
from vispeech.study.clmm import fit_clmm

R_PACKAGES = "R with ordinal, car, emmeans and jsonlite (apt-get install r-base-core r-cran-ordinal r-cran-car " \
             "r-cran-emmeans r-cran-jsonlite)"
COLUMNS = ["participant", "task", "trial", "sentence", "audio", "warmup", "check", "position", "model", "left",
           "right", "answer", "ms", "answered_at"]


@cache
def _has_r() -> bool:
    rscript = shutil.which("Rscript")
    if rscript is None:
        return False
    check = "quit(status = !all(sapply(c('ordinal', 'car', 'emmeans', 'jsonlite'), requireNamespace, quietly = TRUE)))"
    return subprocess.run([rscript, "-e", check], capture_output=True, check=False).returncode == 0


@pytest.fixture
def r():
    """R with its packages (skips without, fails under CI)."""
    require(_has_r(), R_PACKAGES)


def simulate(effects=(0.0, 0.8, 1.6), participants=20, sentences=10, seed=0, pairwise=False) -> pd.DataFrame:
    """Answers in ``answers.csv``'s layout from a proportional-odds model with the thesis's random
    structure: logit P(y <= k) = theta_k - (effect_x + U0_u + S0_s + U1_ux + S1_sx), thresholds at the
    logits of 0.05 ... 0.95 (8 of them: ratings 1-9), participant intercepts SD 1.0 and slopes
    SD 0.3, sentence intercepts SD 0.5 and slopes SD 0.2 (the slopes: per non-reference model).
    Every participant rates every sentence once, all models side by side; with ``pairwise`` each
    pair of models is also judged by the two ratings drawn for it (the higher one wins)."""
    rng = np.random.default_rng(seed)
    k = len(effects)
    theta = logit(np.linspace(0.05, 0.95, 8))
    u0, s0 = rng.normal(0, 1.0, participants), rng.normal(0, 0.5, sentences)
    u1 = np.c_[np.zeros(participants), rng.normal(0, 0.3, (participants, k - 1))]
    s1 = np.c_[np.zeros(sentences), rng.normal(0, 0.2, (sentences, k - 1))]

    def rate(p: int, s: int, m: int) -> int:
        eta = effects[m] + u0[p] + s0[s] + u1[p, m] + s1[s, m]
        return 1 + int((rng.random() > expit(theta - eta)).sum())

    rows = []
    for p in range(participants):
        trial = 0
        for s in rng.permutation(sentences):
            for position, m in enumerate(rng.permutation(k)):
                rows.append([f"p{p}", "rating", trial, f"s{s}", f"s{s}", 0, "", position, f"m{m}", "", "",
                             rate(p, s, m), 900, ""])
            trial += 1
        if pairwise:
            for s in range(sentences):
                for a in range(k):
                    for b in range(a + 1, k):
                        ya, yb = rate(p, s, a), rate(p, s, b)
                        answer = "tie" if ya == yb else "left" if ya > yb else "right"
                        rows.append([f"p{p}", "pairwise", trial, f"s{s}", f"s{s}", 0, "", "", "", f"m{a}", f"m{b}",
                                     answer, 900, ""])
                        trial += 1
    return pd.DataFrame(rows, columns=COLUMNS)


def test_wine_gives_the_ordinal_packages_published_estimates(r, tmp_path):
    """The ordinal package's documented fit (Christensen's clmm tutorial): rating ~ temp + contact + (1|judge)
    on the wine data has thresholds -1.62, 1.51, 4.23, 6.09, tempwarm 3.06, contactyes 1.83 and a
    judge SD of 1.13 (variance 1.28)."""
    path = tmp_path / "wine.csv"
    subprocess.run(["Rscript", "-e", f"write.csv(ordinal::wine, '{path}', row.names = FALSE)"], check=True)
    wine = pd.read_csv(path)
    fit = fit_clmm(wine, "rating ~ temp + contact + (1|judge)", factors=["judge"], term="temp",
                   proportional_odds="rating ~ temp + contact")
    assert fit["formula"] == "rating ~ temp + contact + (1|judge)" and fit["warnings"] == []
    assert [round(t["estimate"], 2) for t in fit["thresholds"]] == [-1.62, 1.51, 4.23, 6.09]
    fixed = {f["name"]: f for f in fit["fixed"]}
    assert round(fixed["tempwarm"]["estimate"], 2) == 3.06 and round(fixed["contactyes"]["estimate"], 2) == 1.83
    assert round(fixed["contactyes"]["estimate"], 6) == 1.834885
    (judge,) = fit["random"]
    assert (judge["group"], round(judge["sd"], 2), round(judge["variance"], 2)) == ("judge", 1.13, 1.28)
    assert (fit["nobs"], fit["groups"], round(fit["log_lik"], 2)) == (72, {"judge": 9}, -81.57)
    assert fit["convergence"]["code"] == 0 and fit["convergence"]["max_grad"] < 1e-3
    # car's type-II Wald chi-square of a one-coefficient term is z squared; emmeans' pair is the coefficient
    wald = {a["term"]: a for a in fit["anova"]}
    assert wald["temp"]["chisq"] == pytest.approx(fixed["tempwarm"]["z"] ** 2, rel=1e-6)
    (pair,) = fit["pairs"]
    assert (pair["a"], pair["b"]) == ("cold", "warm") and pair["estimate"] == pytest.approx(-3.063, abs=1e-3)
    warm = [p["probability"] for p in fit["probabilities"] if p["level"] == "warm"]
    assert len(warm) == 5 and sum(warm) == pytest.approx(1)
    # nominal_test as R prints it: temp's nominal effect LRT 3.1750 on 3 df, p 0.3654
    nominal = fit["proportional_odds"]["nominal"]["temp"]
    assert (nominal["df"], round(nominal["lrt"], 3), round(nominal["p"], 4)) == (3, 3.175, 0.3654)


def test_a_formula_that_fails_falls_back(r):
    frame = simulate(participants=6, sentences=3, seed=1)
    frame = analysis.rating_frame(frame, ["m0", "m1", "m2"])
    fit = fit_clmm(frame, "y ~ x + (1 | nowhere)", fallbacks=[SENTENCE_FORMULA])
    assert [a["formula"] for a in fit["attempts"]] == ["y ~ x + (1 | nowhere)", SENTENCE_FORMULA]
    assert "nowhere" in fit["attempts"][0]["error"] and fit["formula"] == SENTENCE_FORMULA
    assert [f["name"] for f in fit["fixed"]] == ["xm1", "xm2"]


@pytest.fixture(scope="module")
def thesis_fits():
    """The thesis's model on simulated ratings with model effects 0, 0.8, 1.6 on the logit scale
    (``planted``) and with none (``null``), 20 participants and 10 sentences (600 ratings) each:
    two R processes at once (each fit of the random-slope model takes about 30 s)."""
    require(_has_r(), R_PACKAGES)
    with ThreadPoolExecutor(2) as pool:
        planted = pool.submit(analyse_answers, simulate(seed=0))
        null = pool.submit(analyse_answers, simulate(effects=(0.0, 0.0, 0.0), seed=0))
        return {"planted": planted.result().tasks["rating"], "null": null.result().tasks["rating"]}


def test_the_thesis_model_finds_a_planted_effect(thesis_fits):
    rating = thesis_fits["planted"]
    assert rating.fit["formula"] == SLOPES_FORMULA and rating.fit["convergence"]["code"] == 0
    assert rating.wald["df"] == 2 and rating.wald["p"] < 0.001
    fixed = {f["name"]: f["estimate"] for f in rating.fit["fixed"]}
    # ±0.5: the estimates' sampling SD is 0.18-0.25 (20 seeds; ±0.35 missed 4 of their 40 estimates, ±0.5 none)
    assert fixed["xm1"] == pytest.approx(0.8, abs=0.5) and fixed["xm2"] == pytest.approx(1.6, abs=0.5)
    pairs = {(p["a"], p["b"]): p for p in rating.fit["pairs"]}
    assert pairs["m0", "m1"]["estimate"] < 0 and pairs["m1", "m2"]["estimate"] < 0
    assert pairs["m0", "m2"]["estimate"] < pairs["m0", "m1"]["estimate"] and pairs["m0", "m2"]["p"] < 0.001
    means = [m["mean"] for m in rating.fit["means"]]
    assert means == sorted(means)
    assert rating.proportional_odds["passes"]
    assert {u["group"] for u in rating.fit["random"]} == {"u", "s"} and len(rating.fit["correlations"]) == 6
    assert len(rating.sentence_fits) == 10


def test_the_thesis_model_finds_nothing_where_nothing_was_planted(thesis_fits):
    rating = thesis_fits["null"]
    assert rating.fit["formula"] == SLOPES_FORMULA
    assert rating.wald["p"] > 0.05
    assert all(p["p"] > 0.05 for p in rating.fit["pairs"])


def _answers(rows: list[list]) -> pd.DataFrame:
    """Answers from short rows: participant, task, trial, sentence, warmup, check, model | left,right, answer."""
    out = []
    for participant, task, trial, sentence, warmup, check, models, answer in rows:
        if task == "rating":
            for position, (model, rating) in enumerate(zip(models.split(","), answer)):
                out.append([participant, task, trial, sentence, sentence, warmup, check, position, model, "", "",
                            str(rating), 800, ""])
        else:
            left, right = models.split(",")
            out.append([participant, task, trial, sentence, sentence, warmup, check, "", "", left, right, answer,
                        800, ""])
    return pd.DataFrame(out, columns=COLUMNS)


PAIRWISE = [
    ["p1", "pairwise", 0, "s1", 1, "", "A,B", "left"],     # warm-up: left out
    ["p1", "pairwise", 1, "s1", 0, "", "A,B", "left"],     # A wins
    ["p1", "pairwise", 2, "s1", 0, "", "C,A", "left"],     # C beats A
    ["p1", "pairwise", 3, "s1", 0, "identical", "A,A", "tie"],  # check: left out
    ["p1", "pairwise", 4, "s2", 0, "", "B,A", "tie"],      # tie
    ["p1", "pairwise", 5, "s2", 0, "", "B,C", "right"],    # C beats B
    ["p2", "pairwise", 0, "s1", 0, "", "B,A", "left"],     # B beats A
    ["p2", "pairwise", 1, "s2", 0, "mismatched", "A,B", "left"],  # check: left out
    ["p2", "pairwise", 2, "s2", 0, "", "A,B", "right"],    # B wins
    ["p2", "pairwise", 3, "s2", 0, "", "C,B", "tie"],      # tie
]


def test_pairwise_answers_give_points_and_win_tables():
    kept, exclusions = analysis._exclude(analysis.check_answers(_answers(PAIRWISE)), None, False)
    assert (exclusions.warmup_rows, exclusions.check_rows) == (1, 2)
    points = points_frame(kept, ["A", "B", "C"])
    assert len(points) == 2 * 7
    assert points[["u", "trial", "x", "y"]].head(4).values.tolist() == [
        ["p1", 1, "A", 2], ["p1", 1, "B", 0], ["p1", 2, "C", 2], ["p1", 2, "A", 0]]
    assert (points.groupby(["u", "trial"])["y"].sum() == 2).all()  # win + loss, or tie + tie
    wins = win_table(points, ["A", "B", "C"]).set_index(["sentence", "a", "b"])
    counts = wins[["a_wins", "ties", "b_wins"]].apply(tuple, axis=1).to_dict()
    assert counts == {
        ("s1", "A", "B"): (1, 0, 1), ("s2", "A", "B"): (0, 1, 1), (ALL_SENTENCES, "A", "B"): (1, 1, 2),
        ("s1", "A", "C"): (0, 0, 1), ("s2", "A", "C"): (0, 0, 0), (ALL_SENTENCES, "A", "C"): (0, 0, 1),
        ("s1", "B", "C"): (0, 0, 0), ("s2", "B", "C"): (0, 1, 1), (ALL_SENTENCES, "B", "C"): (0, 1, 1),
    }


def test_rating_wins_compare_one_participants_ratings_of_one_trial():
    answers = _answers([
        ["p1", "rating", 0, "s1", 1, "", "A,B", [9, 1]],         # warm-up: left out
        ["p1", "rating", 1, "s1", 0, "", "B,A", [3, 7]],         # A beats B
        ["p1", "rating", 2, "s1", 0, "identical", "A,A,B", [5, 5, 5]],  # check: left out
        ["p1", "rating", 3, "s2", 0, "", "A,B", [4, 4]],         # tie
        ["p2", "rating", 0, "s1", 0, "", "A,B", [2, 6]],         # B beats A
        ["p2", "rating", 1, "s2", 0, "", "B,A", [8, 1]],         # B beats A
    ])
    kept, exclusions = analysis._exclude(analysis.check_answers(answers), None, False)
    assert (exclusions.warmup_rows, exclusions.check_rows) == (2, 3)
    wins = win_table(analysis.rating_frame(kept, ["A", "B"]), ["A", "B"])
    assert wins.values.tolist() == [["s1", "A", "B", 1, 0, 1], ["s2", "A", "B", 0, 1, 1],
                                    [ALL_SENTENCES, "A", "B", 1, 1, 2]]


def test_warmups_checks_and_failed_participants_stay_out_of_the_fits(monkeypatch):
    sent = []

    def fake_r(jobs):
        sent.extend(jobs)
        attempts = [{"formula": f, "error": "not run"} for f in jobs[0][1]["formulas"]]
        return [{"formula": None, "error": "not run", "attempts": attempts} for _ in jobs], {}

    monkeypatch.setattr(analysis, "run_clmm", fake_r)
    people = pd.DataFrame({"participant": ["p1", "p2"], "passed_identical": ["1", "0"],
                           "passed_mismatched": ["1", ""]})
    result = analyse_answers(_answers(PAIRWISE), participants=people, exclude_failed_checks=True)
    frame, job = sent[0]
    assert job["formulas"] == [SLOPES_FORMULA, INTERCEPTS_FORMULA] and job["levels"] == ["0", "1", "2"]
    assert len(frame) == 2 * 4 and set(frame["u"]) == {"p1"}  # p2 failed the identical check
    assert result.exclusions.participants == ("p2",)
    assert result.exclusions.checks == {"identical": {"passed": 1, "failed": 1, "none": 0},
                                        "mismatched": {"passed": 1, "failed": 0, "none": 1}}
    assert result.tasks["pairwise"].warnings[0] == (f"no model could be fitted ({SLOPES_FORMULA}: not run; "
                                                    f"{INTERCEPTS_FORMULA}: not run)")


def _analyse(*args):
    return CliRunner().invoke(main, ["study", "analyse", *map(str, args)])


def test_the_command_writes_the_analysis(r, tmp_path):
    path = tmp_path / "answers.csv"
    simulate(participants=10, sentences=4, seed=3, pairwise=True).to_csv(path, index=False)
    out = tmp_path / "out"
    result = _analyse(path, "-o", out, "--no-random-slopes", "--models", "m2,m1,m0")
    assert result.exit_code == 0, result.output
    assert "rating: 120 answers by 10 participants on 4 sentences; models m2, m1, m0" in result.output
    assert "pairwise: 120 answers" in result.output
    assert result.output.count("Wald chi2(2)") == 2 and "m2 - m0: " in result.output
    names = {p.name for p in out.iterdir()}
    for task in ("rating", "pairwise"):
        assert {f"{task}_{n}.csv" for n in ("coefficients", "anova", "pairs", "probabilities", "means", "wins",
                                             "sentences", "proportional_odds", "random")} <= names
        assert {f"{task}_{n}.{kind}" for n in ("probabilities", "wins") for kind in ("png", "svg")} <= names
    assert (out / "rating_probabilities.png").read_bytes()[:4] == b"\x89PNG"
    saved = json.loads((out / "analysis.json").read_text())
    assert saved["tasks"]["rating"]["fit"]["formula"] == INTERCEPTS_FORMULA
    assert saved["tasks"]["pairwise"]["models"] == ["m2", "m1", "m0"]
    pairs = pd.read_csv(out / "rating_pairs.csv")
    assert pairs[["a", "b"]].values.tolist() == [["m2", "m1"], ["m2", "m0"], ["m1", "m0"]]
    probabilities = pd.read_csv(out / "pairwise_probabilities.csv")
    assert sorted(probabilities["points"].unique()) == [0, 1, 2]
    html = (out / "report.html").read_text()
    assert "Wald χ²(2)" in html and 'src="rating_wins.png"' in html


BAD = {
    "missing columns": ("participant,task,trial,sentence\np1,rating,0,s1\n", "has no columns warmup, check"),
    "rating 10": (None, "rating '10' is not a whole number from 1 to 9"),
    "empty file": ("", "is empty"),
    "header only": (",".join(COLUMNS) + "\n", "holds no answers"),
    "one model": (None, "one model only (m0)"),
    "a face twice": (None, "model 'm2' shown twice in trial 0 of participant 'p0'"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_answers_are_one_line_and_write_nothing(tmp_path, case):
    text, message = BAD[case]
    if case == "rating 10":
        frame = simulate(participants=2, sentences=2)
        frame.loc[3, "answer"] = 10
        text = frame.to_csv(index=False)
    elif case == "one model":
        frame = simulate(participants=2, sentences=2)
        text = frame[frame["model"] == "m0"].to_csv(index=False)
    elif case == "a face twice":
        frame = simulate(participants=2, sentences=2)
        frame.loc[frame.index[0], "model"] = frame.loc[frame.index[1], "model"]
        text = frame.to_csv(index=False)
    path = tmp_path / "answers.csv"
    path.write_text(text)
    result = _analyse(path, "-o", tmp_path / "out")
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: ") and message in result.output and result.output.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_missing_r_is_one_line(tmp_path, monkeypatch):
    path = tmp_path / "answers.csv"
    simulate(participants=2, sentences=2).to_csv(path, index=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    result = _analyse(path, "-o", tmp_path / "out")
    assert result.exit_code == 2
    assert result.output == ("error: the study analysis needs R (Rscript was not found): apt-get install "
                             "r-base-core r-cran-ordinal r-cran-car r-cran-emmeans r-cran-jsonlite\n")


def test_missing_r_packages_are_named(r, monkeypatch):
    monkeypatch.setenv("R_LIBS_SITE", "/nonexistent")
    monkeypatch.setenv("R_LIBS_USER", "/nonexistent")
    monkeypatch.delenv("R_LIBS", raising=False)
    with pytest.raises(VispeechError, match=r"needs the R packages ordinal, car, emmeans, jsonlite: apt-get install"):
        fit_clmm(pd.DataFrame({"y": [1, 2], "x": ["a", "b"]}), "y ~ x")
