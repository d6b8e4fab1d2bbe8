"""The shipped default model (GRID-trained network + its recommended post-processing)."""

import json
import tomllib
from dataclasses import replace
from fnmatch import fnmatch
from pathlib import Path

import numpy as np
import pytest

from vispeech import Phone, PhoneSequence, Track, VispeechError
from vispeech.models.registry import MODEL_NAMES, PRETRAINED, create_model, load_model, pretrained_path
from vispeech.models.networks.tdnn import TimeDelayNetwork
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.pipeline import DEFAULT_MODEL, animate, postprocess_config
from vispeech.postprocess import PostprocessConfig, SoftCeiling, postprocess
from vispeech.postprocess.overlays import anchor_frames, consonant_overlays

ROOT = Path(__file__).resolve().parents[1]
PRETRAINED_DIR = ROOT / "src" / "vispeech" / "models" / "pretrained"


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
    assert DEFAULT_MODEL in PRETRAINED and DEFAULT_MODEL in MODEL_NAMES
    assert isinstance(default, TimeDelayNetwork) and default.is_trained
    assert default.encoding.kind == "features"  # language-independent: the same model speaks sv and en
    assert {"jawOpen", "mouthClose", "mouthPucker"} <= set(default.channels)


@pytest.mark.parametrize("name", list(PRETRAINED))
def test_shipped_models_load_small_and_trained(name):
    folder = pretrained_path(name)
    assert folder.is_dir() and folder.parent == PRETRAINED_DIR
    assert sum(p.stat().st_size for p in folder.iterdir()) < 3_000_000
    model = create_model(name)
    assert model.is_trained and model.postprocessing == json.loads((folder / "config.json").read_text())[
        "postprocessing"]
    with pytest.raises(VispeechError, match="takes no options"):
        create_model(name, hidden=3)


def test_shipped_files_are_package_data():
    """Every file the loader needs matches a package-data pattern, so wheels carry it."""
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["*"]
    needed = [p for name in PRETRAINED for p in pretrained_path(name).iterdir() if p.suffix != ".png"]
    assert {p.name for p in needed} >= {"config.json", "weights.safetensors"}
    for path in [*needed, PRETRAINED_DIR / "MODEL_CARD.md"]:
        assert any(fnmatch(path.name, pattern) for pattern in patterns), path


def test_recommended_postprocessing_suits_learned_jaw(default):
    config = postprocess_config(default)
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
    expected = postprocess(default.predict(phones, 25), phones, postprocess_config(default))
    np.testing.assert_array_equal(animate(phones, default, 25).values, expected.values)
    plain = postprocess(default.predict(phones, 25), phones, PostprocessConfig())
    assert not np.allclose(plain["jawOpen"], expected["jawOpen"])  # the defaults would shift the jaw
    np.testing.assert_array_equal(animate(phones, default, 25, PostprocessConfig()).values, plain.values)
    np.testing.assert_array_equal(animate(phones, default, 25, False).values, default.predict(phones, 25).values)


@pytest.mark.parametrize("name", ["ohman", "tdnn-beskow"])
def test_saved_postprocessing_round_trips(tmp_path, name):
    model = create_model(name) if name == "ohman" else load_model(DEFAULT_MODEL)
    if name == "ohman":
        assert model.postprocessing is None and postprocess_config(model) == PostprocessConfig()
    model.postprocessing = {"jaw_shift": 0.02, "ceilings": {"jawOpen": {"threshold": 0.3, "maximum": 0.4}},
                            "fade_out": {"default": 1.0}}
    loaded = load_model(model.save(tmp_path / "saved"))
    assert loaded.postprocessing == model.postprocessing
    config = postprocess_config(loaded)
    assert config.jaw_shift == 0.02 and config.fade_out == {"default": 1.0}
    assert config.ceilings == {"jawOpen": SoftCeiling(threshold=0.3, maximum=0.4)}


def test_bad_recommended_postprocessing_is_refused(tmp_path):
    model = create_model("baseline")
    folder = model.save(tmp_path / "m")
    config = json.loads((folder / "config.json").read_text())
    assert "postprocessing" not in config
    (folder / "config.json").write_text(json.dumps({**config, "postprocessing": [1, 2]}))
    with pytest.raises(VispeechError, match="postprocessing must be an object"):
        load_model(folder)
    phones = sequence("M AA", "en")
    for settings, message in [({"jaw_shfit": 0.1}, "unknown post-processing settings: jaw_shfit"),
                              ({"jaw_shift": 2.0}, "jaw_shift"),
                              ({"ceilings": {"jawOpen": {"threshold": 0.5}}}, "bad post-processing"),
                              ({"overlay_features": ["bilabal"]}, "bilabal")]:
        model.postprocessing = settings
        with pytest.raises(VispeechError, match=message):
            animate(phones, model, 30)


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
