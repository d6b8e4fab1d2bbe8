"""The shipped default model (GRID-trained network + its recommended post-processing)."""

import json
import tomllib
from dataclasses import replace
from fnmatch import fnmatch
from pathlib import Path

import numpy as np
import pytest

from vispeech import Phone, PhoneSequence, Track, VispeechError
from vispeech.models.persistence import RETIRED_PARAMS
from vispeech.models.registry import PRETRAINED, RUNNABLE, create_model, load_model, pretrained_path
from vispeech.models.rules.baseline import Baseline
from vispeech.models.networks.tdnn import TimeDelayNetwork
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.pipeline import DEFAULT_MODEL, animate
from vispeech.postprocess import PostprocessConfig, postprocess
from vispeech.postprocess.overlays import anchor_frames, consonant_overlays
from vispeech.targets.presets import PRESETS

ROOT = Path(__file__).resolve().parents[1]
PRETRAINED_DIR = ROOT / "src" / "vispeech" / "models" / "pretrained"


def recommended(model) -> PostprocessConfig:
    """The post-processing settings of the preset ``model`` recommends."""
    return PostprocessConfig.from_preset(model.postprocessing)


def shipped_folder(name: str) -> Path:
    """The folder of shipped model ``name``; skips the test while that model is not shipped yet."""
    folder = pretrained_path(name)
    if not folder.is_dir():
        pytest.skip(f"shipped model {name} not trained yet ({folder} absent)")
    return folder


def sequence(symbols: str, language: str, length: float = 0.12) -> PhoneSequence:
    """``symbols`` (space-separated) of ``length`` s each between 0.3 s silences."""
    phones, t = [Phone("sil", 0.0, 0.3)], 0.3
    for symbol in symbols.split():
        phones.append(Phone(symbol, t, t + length))
        t += length
    phones.append(Phone("sil", t, t + 0.3))
    return PhoneSequence(phones, language)


@pytest.fixture(scope="module")
def default():
    return load_model(DEFAULT_MODEL)


def test_default_is_the_shipped_features_network(default):
    assert DEFAULT_MODEL in PRETRAINED and DEFAULT_MODEL in RUNNABLE
    assert isinstance(default, TimeDelayNetwork) and default.is_fitted
    assert default.name == DEFAULT_MODEL and default.family == "tdnn-beskow"
    assert default.encoding_.kind == "features"  # language-independent: the same model speaks sv and en
    assert {"jawOpen", "mouthClose", "mouthPucker"} <= set(default.channels)


@pytest.mark.parametrize("name", list(PRETRAINED))
def test_shipped_models_load_small_and_trained(name):
    assert pretrained_path(name).parent == PRETRAINED_DIR
    folder = shipped_folder(name)
    config = json.loads((folder / "config.json").read_text())
    audio = config["input"] == "audio"  # 256-channel audio networks: 5 to 6.4 MB of float32 weights (Whisper base's)
    assert sum(p.stat().st_size for p in folder.iterdir()) < (6_500_000 if audio else 3_000_000)
    model = load_model(name)
    assert model.is_fitted and model.name == config["name"] == name and model.family == config["family"]
    assert model.postprocessing == config["postprocessing"] == ("audio" if audio else "learned-jaw")
    params = model.get_params()  # hyper-parameters added since a model was saved come with their defaults
    assert list(model.channels) == config["channels"] and {k: params[k] for k in config["params"]} == config["params"]
    added = set(params) - set(config["params"])  # added since it was saved: the family's defaults
    assert all(params[k] == type(model).defaults[k] for k in added)
    assert not RETIRED_PARAMS & set(config["params"])  # run settings (fit's keywords) are not shipped
    with pytest.raises(VispeechError, match="unknown model family"):  # a shipped model is not a family
        create_model(name, hidden=3)


def test_shipped_files_are_package_data():
    """Every file the loader needs matches a package-data pattern, so wheels carry it."""
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["*"]
    shipped = [pretrained_path(name) for name in PRETRAINED if pretrained_path(name).is_dir()]
    assert pretrained_path(DEFAULT_MODEL) in shipped
    needed = [p for folder in shipped for p in folder.iterdir() if p.suffix != ".png"]
    assert {p.name for p in needed} >= {"config.json", "weights.safetensors"}
    for path in [*needed, PRETRAINED_DIR / "MODEL_CARD.md"]:
        assert any(fnmatch(path.name, pattern) for pattern in patterns), path


def test_recommended_postprocessing_suits_learned_jaw(default):
    assert default.postprocessing == "learned-jaw"
    config = recommended(default)
    assert config == PostprocessConfig(**PRESETS["learned-jaw"])
    assert config.jaw_shift == 0 and not config.ceilings and config.keep_jaw
    assert set(config.overlay_features) == {"bilabial", "labiodental"}


@pytest.mark.parametrize("language,symbols", [
    ("en", "HH AH L OW M AY P AE B"),
    ("sv", "h E j m 2: p a b U rt A: f"),
])
def test_predicts_both_languages_with_closures(default, language, symbols):
    phones = sequence(symbols, language)
    track = animate(phones, DEFAULT_MODEL, fps=30)
    assert track.n_frames == phones.n_frames(30) and track.fps == 30
    assert np.all((track.values >= 0) & (track.values <= 1))
    raw = default.predict(phones, 30)
    jaw = raw["jawOpen"]
    assert jaw.max() > 0.1 and jaw.max() - jaw.min() > 0.05  # the jaw moves with the vowels
    aperture = lip_aperture(track)
    bilabials = [p for p in phones if p.symbol.lower() in ("p", "b", "m")]
    anchors = anchor_frames(np.array([p.start for p in bilabials]), np.array([p.end for p in bilabials]), 30,
                            track.n_frames)
    assert np.all(aperture[anchors] <= LIP_CLOSED)
    # keep_jaw: post-processing closes the lips with mouthClose and leaves the learned jaw at the bilabials
    np.testing.assert_allclose(track["jawOpen"][anchors], np.minimum(track["jawOpen"][anchors], jaw[anchors]))


def test_animate_uses_the_models_recommended_postprocessing(default):
    phones = sequence("M AA P IY F", "en")
    expected = postprocess(default.predict(phones, 25), phones, recommended(default))
    np.testing.assert_array_equal(animate(phones, default, 25).values, expected.values)
    plain = postprocess(default.predict(phones, 25), phones, PostprocessConfig())
    assert not np.allclose(plain["jawOpen"], expected["jawOpen"])  # the defaults would shift the jaw
    np.testing.assert_array_equal(animate(phones, default, 25, PostprocessConfig()).values, plain.values)
    np.testing.assert_array_equal(animate(phones, default, 25, "none").values, default.predict(phones, 25).values)


@pytest.mark.parametrize("name", ["ohman", DEFAULT_MODEL])
def test_saved_postprocessing_round_trips(tmp_path, name):
    model = load_model(name)
    if name == "ohman":  # authored parameters: every post-processing step with its defaults
        assert model.postprocessing == "authored" and recommended(model) == PostprocessConfig()
    else:
        assert model.postprocessing == "learned-jaw"
    folder = model.save(tmp_path / "saved")
    assert json.loads((folder / "config.json").read_text())["postprocessing"] == model.postprocessing
    loaded = load_model(folder)
    assert loaded.postprocessing == model.postprocessing and recommended(loaded) == recommended(model)
    assert loaded.name == model.name


class _Unknown(Baseline):
    """A model recommending a preset that does not exist."""

    @property
    def postprocessing(self) -> str:
        return "no-such-preset"


def test_bad_recommended_postprocessing_is_refused(tmp_path):
    folder = create_model("baseline").save(tmp_path / "m")
    config = json.loads((folder / "config.json").read_text())
    assert config["postprocessing"] == "authored"
    for value in ([1, 2], {"jaw_shift": 0.0}, None):
        (folder / "config.json").write_text(json.dumps({**config, "postprocessing": value}))
        with pytest.raises(VispeechError, match="postprocessing must be a str"):
            load_model(folder)
    phones = sequence("M AA", "en")
    with pytest.raises(VispeechError, match="unknown post-processing preset 'no-such-preset'"):
        animate(phones, _Unknown(), 30)
    with pytest.raises(VispeechError, match="unknown post-processing preset"):
        PostprocessConfig.from_preset("learned_jaw")
    with pytest.raises(VispeechError, match="jaw_shift"):
        PostprocessConfig(jaw_shift=2.0)
    np.testing.assert_array_equal(animate(phones, _Unknown(), 30, "none").values,
                                  create_model("baseline").predict(phones, 30).values)


def test_keep_jaw_reaches_the_viseme_opening_through_mouth_close():
    phones = sequence("AA M AA F AA T AA", "en")
    n = phones.n_frames(30)
    channels = ("jawOpen", "mouthClose")
    track = Track(np.column_stack([np.full(n, 0.25), np.zeros(n)]), channels, 30)
    kept = consonant_overlays(track, phones, keep_jaw=True)
    np.testing.assert_array_equal(kept["jawOpen"], track["jawOpen"])
    m, f = (p for p in phones if p.symbol in ("M", "F"))
    anchor_m, anchor_f = anchor_frames(np.array([m.start, f.start]), np.array([m.end, f.end]), 30, n)
    assert kept["mouthClose"][anchor_m] == pytest.approx(0.25)  # /m/: opening 0, lips shut at any jaw height
    assert kept["jawOpen"][anchor_f] - kept["mouthClose"][anchor_f] == pytest.approx(0.05 - 0.02)  # /f/'s opening
    lowered = consonant_overlays(track, phones)
    assert lowered["jawOpen"][anchor_m] == pytest.approx(0.08)  # the default lowers the jaw to the viseme's
    labial = consonant_overlays(track, phones, features=["bilabial", "labiodental"])
    t_frames = slice(*np.searchsorted(np.arange(n) / 30, [phones.phones[6].start, phones.phones[6].end]))
    np.testing.assert_array_equal(labial["jawOpen"][t_frames], 0.25)  # /t/ is left alone
    assert lowered["jawOpen"][t_frames].min() < 0.25
    with pytest.raises(VispeechError, match="unknown articulatory features"):
        consonant_overlays(track, phones, features=["labial"])


def test_scores_on_grid_validation_utterances(default, shared_dir):
    """Sanity of the shipped weights on a few validation utterances (never the test split)."""
    from vispeech.corpus import align_corpus, read_grid
    from vispeech.evaluation import evaluate_models

    corpus = read_grid(shared_dir / "data" / "grid_s1")
    validation = corpus.split("validation")
    subset = replace(validation, utterances=list(validation)[:8])
    align_corpus(subset, progress=False)
    result = evaluate_models(subset, {"default": default}, channels=["jawOpen"]).models[0]
    assert result.scores["jawOpen"]["r"] > 0.75
    assert result.closures.bilabial_rate >= 90
