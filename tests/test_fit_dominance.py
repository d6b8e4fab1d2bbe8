"""Least-squares fitting of the Cohen–Massaro and Öhman models (vispeech.models.rules.dominance_fit)."""

from pathlib import Path

import numpy as np
import pytest
from conftest import random_sentence

from vispeech.alignment.phones import PhoneSequence
from vispeech.corpus import Corpus, Utterance
from vispeech.errors import VispeechError
from vispeech.models.rules import cohen_massaro, ohman
from vispeech.models.contract import Estimator
from vispeech.models.fitting import Splits
from vispeech.models.rules.cohen_massaro import CohenMassaro
from vispeech.models.rules.dominance_fit import ChannelProblem, FitData, PhoneTying, levenberg_marquardt
from vispeech.models.registry import load_folder
from vispeech.models.rules.ohman import Ohman
from vispeech.phonetics.features import phone_rows
from vispeech.motion.track import Track
from vispeech.postprocess import PostprocessConfig
from vispeech.targets.presets import PRESETS

SYMBOLS = ("AA", "IY", "UW", "B", "S", "L")
CHANNELS = ("jawOpen", "mouthPucker")
FPS = 50.0


def sentence(rng: np.random.Generator, symbols=SYMBOLS, language: str = "en") -> PhoneSequence:
    """Silence, 4–7 random phones of ``symbols``, silence."""
    return random_sentence(rng, symbols, language)


def recorded_by(model: Estimator, seeds, channels=CHANNELS) -> list[Utterance]:
    """Utterances whose tracks are ``model``'s own predictions of ``channels`` at 50 fps."""
    out = []
    for seed in seeds:
        phones = sentence(np.random.default_rng(seed))
        out.append(Utterance(id=f"u{seed}", phones=phones, track=model.predict(phones, FPS).select(channels)))
    return out


def true_cohen_massaro(seed: int = 0) -> tuple[CohenMassaro, dict]:
    """A Cohen–Massaro model with random per-phone targets, α, θ, φ and c on CHANNELS."""
    rng = np.random.default_rng(seed)
    truth = {name: {s: dict(zip(CHANNELS, rng.uniform(low, high, len(CHANNELS)))) for s in SYMBOLS + ("sil",)}
             for name, low, high in (("targets", 0.05, 0.95), ("alpha", 0.5, 2.0), ("theta", 8.0, 25.0),
                                     ("phi", 8.0, 25.0), ("c", 0.8, 1.5))}
    params = {"targets": {"en": truth["targets"]}}
    for name in ("alpha", "theta", "phi", "c"):
        params[name] = {"default": 1.0 if name != "theta" and name != "phi" else 16.0,
                        **{f"en:{s}": v for s, v in truth[name].items()}}
    return CohenMassaro(**params), truth


def true_ohman(seed: int = 0) -> tuple[Ohman, dict]:
    """An Öhman model with random per-phone targets and consonant factors w in [0.5, 1] on CHANNELS."""
    rng = np.random.default_rng(seed)
    targets = {s: dict(zip(CHANNELS, rng.uniform(0.05, 0.95, len(CHANNELS)))) for s in SYMBOLS + ("sil",)}
    w = {s: dict(zip(CHANNELS, rng.uniform(0.5, 1.0, len(CHANNELS)))) for s in ("B", "S", "L")}
    model = Ohman(targets={"en": targets}, w_c={"default": 0.5, **{f"en:{s}": v for s, v in w.items()}})
    return model, {"targets": targets, "w": w}


def mse(model: Estimator, utterances) -> float:
    errors = [model.predict(u.phones, FPS).select(CHANNELS).values - u.track.values for u in utterances]
    return float(np.mean(np.concatenate(errors) ** 2))


def numeric_jacobian(design, base, channel: int, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    columns = []
    for k in range(len(x)):
        up, down = x.copy(), x.copy()
        up[k] += step
        down[k] -= step
        columns.append((design.residuals(base, channel, up, False)[0]
                        - design.residuals(base, channel, down, False)[0]) / (2 * step))
    return np.column_stack(columns)


def test_cohen_massaro_jacobian_matches_finite_differences():
    model = CohenMassaro()
    data = FitData.gather(model, recorded_by(true_cohen_massaro()[0], range(3)), CHANNELS)
    tying = PhoneTying.of("en", data.train)
    design = cohen_massaro._Design(data.train, 6, tying)
    rng = np.random.default_rng(1)
    n = len(tying)
    x = np.concatenate([rng.uniform(0.1, 0.9, n), rng.uniform(-1, 1, n), rng.uniform(0, 1.5, 2 * n),
                        rng.uniform(-0.3, 0.4, n)])
    m = model.channels.index("mouthPucker")
    tables = model.tables("en")
    base = (tables["targets"][:, m], np.log(tables["alpha"][:, m]), tables["theta"][:, m], tables["phi"][:, m],
            tables["c"][:, m])
    r, jacobian = design.residuals(base, 1, x, True)
    assert jacobian.shape == (len(r), 5 * n) and np.abs(jacobian).max(axis=0).min() > 0
    np.testing.assert_allclose(jacobian, numeric_jacobian(design, base, 1, x), rtol=1e-5, atol=1e-8)


def test_ohman_jacobian_matches_finite_differences():
    model = Ohman()
    data = FitData.gather(model, recorded_by(true_ohman()[0], range(3)), CHANNELS)
    tying = PhoneTying.of("en", data.train)
    factors = PhoneTying.of("en", data.train, rows=phone_rows("en").mask("consonant"))
    design = ohman._Design(data.train, tying, factors)
    x = np.random.default_rng(2).uniform(0.1, 0.9, len(tying) + len(factors))
    m = model.channels.index("jawOpen")
    base = (model.tables("en")["targets"][:, m], model.tables("en")["w_c"][:, m])
    r, jacobian = design.residuals(base, 0, x, True)
    assert jacobian.shape == (len(r), len(tying) + 3) and np.abs(jacobian).max(axis=0).min() > 0
    np.testing.assert_allclose(jacobian, numeric_jacobian(design, base, 0, x), rtol=1e-6, atol=1e-9)


def test_cohen_massaro_fit_recovers_the_parameters_that_made_the_data():
    truth_model, truth = true_cohen_massaro()
    model = CohenMassaro(channels=list(CHANNELS)).fit(recorded_by(truth_model, range(40)), progress=False)
    assert model.fitted_channels_ == CHANNELS and list(model.tables_) == ["en"]
    rows = [phone_rows("en").symbols.index(s) for s in SYMBOLS + ("sil",)]
    columns = [model.channels.index(c) for c in CHANNELS]
    fitted = model.tables_["en"]
    assert set(fitted) == {"targets", "alpha", "theta", "phi", "c"}
    assert model.tables("en") is fitted and model.tables("sv") is not fitted  # learned where fitted
    for name, table in fitted.items():
        expected = np.array([[truth[name][s][c] for c in CHANNELS] for s in SYMBOLS + ("sil",)])
        got = table[np.ix_(rows, columns)]
        if name == "alpha":  # α is only defined up to a common factor; the fit holds that of silence
            got = got * expected[-1]
        np.testing.assert_allclose(got, expected, rtol=1e-4, err_msg=name)
    held_out = recorded_by(truth_model, range(100, 110))
    assert mse(model, held_out) < 1e-12 < 1e-4 < mse(CohenMassaro(), held_out)


def test_ohman_fit_recovers_the_parameters_that_made_the_data():
    truth_model, truth = true_ohman()
    model = Ohman(channels=list(CHANNELS)).fit(recorded_by(truth_model, range(30)), progress=False)
    assert model.fitted_channels_ == CHANNELS and set(model.tables_["en"]) == {"targets", "w_c"}
    columns = [model.channels.index(c) for c in CHANNELS]
    learned = model.tables_["en"]
    for table, expected in ((learned["targets"], truth["targets"]), (learned["w_c"], truth["w"])):
        rows = [phone_rows("en").symbols.index(s) for s in expected]
        wanted = np.array([[values[c] for c in CHANNELS] for values in expected.values()])
        np.testing.assert_allclose(table[np.ix_(rows, columns)], wanted, atol=1e-4)


@pytest.mark.parametrize(("cls", "maker"), [(CohenMassaro, true_ohman), (Ohman, true_cohen_massaro)])
def test_fitting_the_other_models_data_lowers_the_error(cls, maker):
    train = recorded_by(maker()[0], range(6))
    before = mse(cls(), train)
    model = cls(channels=list(CHANNELS), max_iterations=20)
    assert model.fit(train, progress=False) is model
    assert mse(model, train) < 0.5 * before
    assert model.history_.train_loss[-1] == pytest.approx(mse(model, train), rel=1e-9)
    assert model.history_.epochs <= 20 and model.history_.best_epoch == model.history_.epochs
    assert all(v is None for v in model.history_.validation_loss)  # a plain list: no validation split


def test_early_stopping_keeps_the_parameters_with_the_lowest_validation_error():
    # training pulls x toward 1, validation toward 0: every step makes validation worse
    problem = ChannelProblem(
        x0=np.zeros(1), lower=np.full(1, -5.0), upper=np.full(1, 5.0),
        residuals=lambda x, jacobian: (x - 1.0, np.ones((1, 1)) if jacobian else None),
        validation=lambda x, jacobian: (x.copy(), None),
    )
    kept, history = levenberg_marquardt({"a": problem}, max_iterations=50, patience=2, progress=False)
    assert kept["a"].tolist() == [0.0]
    assert history.epochs == 2 and history.best_epoch == 0
    assert history.validation_loss == [0.0, 0.0] and history.train_loss == [1.0, 1.0]


def test_fit_stops_early_when_the_validation_data_disagree():
    truth_model, _ = true_cohen_massaro(0)
    other, _ = true_cohen_massaro(1)
    corpus = Splits(recorded_by(truth_model, range(10)), recorded_by(other, range(10, 14)))
    model = CohenMassaro(channels=list(CHANNELS), max_iterations=40, patience=1).fit(corpus, progress=False)
    history = model.history_
    assert history.epochs < 40 and history.best_epoch < history.epochs
    assert history.validation_loss[-1] == min(history.validation_loss)
    # the same training data without the validation split runs on
    unstopped = CohenMassaro(channels=list(CHANNELS), max_iterations=40, patience=1).fit(corpus.train, progress=False)
    assert unstopped.history_.epochs > history.epochs


def test_a_fitted_model_saves_and_loads_to_identical_predictions(tmp_path):
    truth_model, _ = true_cohen_massaro()
    train = recorded_by(truth_model, range(4))
    english = sentence(np.random.default_rng(7), SYMBOLS + ("M", "ZH"))
    swedish = sentence(np.random.default_rng(8), ("a", "m", "s", "u:"), "sv")
    for cls in (CohenMassaro, Ohman):
        model = cls(channels=list(CHANNELS), max_iterations=3)
        params = model.get_params()
        assert model.postprocessing == "authored"
        model.fit(train, progress=False)
        assert model.get_params() == params  # what fitting learns lives in tables_, not in the parameters
        loaded = load_folder(model.save(tmp_path / model.name))
        assert type(loaded) is type(model) and loaded.get_params() == model.get_params()
        assert loaded.fitted_channels_ == CHANNELS and loaded.history_ == model.history_
        for language, tables in model.tables_.items():
            for name, table in tables.items():
                np.testing.assert_array_equal(loaded.tables_[language][name], table)
        assert model.postprocessing == loaded.postprocessing == "learned-jaw"  # a fitted jaw is left to the model
        assert PostprocessConfig.from_preset(loaded.postprocessing) == PostprocessConfig(**PRESETS["learned-jaw"])
        for phones in (english, swedish):
            assert np.array_equal(loaded.predict(phones, 30).values, model.predict(phones, 30).values)
        # phones and languages the data lacks keep their defaults
        assert np.array_equal(model.predict(swedish, 30).values, cls().predict(swedish, 30).values)
        rows, authored = phone_rows("en"), cls().tables("en")["targets"]
        jaw = model.channels.index("jawOpen")
        zh, aa = rows.keys["ZH", False], rows.keys["AA", False]
        assert model.tables_["en"]["targets"][zh, jaw] == authored[zh, jaw]
        assert model.tables_["en"]["targets"][aa, jaw] != authored[aa, jaw]
        other = model.channels.index("mouthSmileLeft")  # not fitted: authored
        np.testing.assert_array_equal(model.tables_["en"]["targets"][:, other], authored[:, other])


def test_fit_data_uses_the_corpus_splits_and_refuses_bad_input():
    rng = np.random.default_rng(3)
    utterances = []
    for k in range(30):
        phones = sentence(rng)
        track = Track(np.zeros((phones.n_frames(25), 1)), ("jawOpen",), 25)
        utterances.append(Utterance(f"s{k}", "", Path("none.wav"), phones.duration, track, phones=phones))
    corpus = Corpus("toy", utterances, 25, ("jawOpen",))
    data = FitData.gather(CohenMassaro(), corpus, None)
    assert data.channels == ("jawOpen",) and data.language == "en"
    assert (len(data.train), len(data.validation)) == (len(corpus.split("train")), len(corpus.split("validation")))
    assert sum(len(r.values) for r in data.train) == sum(u.track.n_frames for u in corpus.split("train"))
    with pytest.raises(VispeechError, match="does not predict"):
        FitData.gather(CohenMassaro(), corpus, ["headYaw"])
    with pytest.raises(VispeechError, match="align"):
        FitData.gather(Ohman(), [Utterance(track=utterances[0].track)], None)
    with pytest.raises(VispeechError, match="empty"):
        CohenMassaro().fit([], progress=False)
    with pytest.raises(VispeechError, match="max_iterations"):
        CohenMassaro(max_iterations=-1).fit(corpus, progress=False)
    with pytest.raises(VispeechError, match="patience"):
        Ohman(patience=0).fit(corpus, progress=False)
    with pytest.raises(VispeechError, match="does not predict"):
        Ohman(channels=["headYaw"]).fit(corpus, progress=False)
    with pytest.raises(VispeechError, match="no parameter 'validation'"):
        CohenMassaro(validation=[])
