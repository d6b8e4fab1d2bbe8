"""The per-phone target table, per-phone specs and the lip aperture."""

import numpy as np
import pytest

from vispeech.errors import VispeechError
from vispeech.targets.tables import (
    TARGET_CHANNELS,
    TargetTable,
    phone_rows,
    phone_targets,
    resolve_spec,
    target_matrix,
)
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import LANGUAGES, get_inventory

APERTURE_CHANNELS = (
    "jawOpen", "mouthClose", "mouthFunnel", "mouthRollLower", "mouthRollUpper", "mouthPressLeft",
    "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight",
)


def aperture_of(targets: dict) -> float:
    values = np.array([[targets[c] or 0.0 for c in TARGET_CHANNELS]])
    return float(lip_aperture(Track(values, TARGET_CHANNELS, 30.0))[0])


def test_channels_cover_the_mouth_and_jaw():
    required = {
        "jawOpen", "jawForward", "mouthClose", "mouthFunnel", "mouthPucker", "mouthSmileLeft", "mouthSmileRight",
        "mouthStretchLeft", "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
        "mouthShrugUpper", "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
        "mouthUpperUpLeft", "mouthUpperUpRight", "tongueOut",
    }
    assert required <= set(TARGET_CHANNELS)


@pytest.mark.parametrize("language, symbols", [("sv", ["p", "b", "m"]), ("en", ["P", "B", "M"])])
def test_bilabial_targets_close_the_lips(language, symbols):
    for symbol in symbols:
        targets = phone_targets(symbol, language)
        assert all(targets[c] is not None for c in APERTURE_CHANNELS), symbol
        assert aperture_of(targets) <= 0.0


@pytest.mark.parametrize("language, symbols", [("sv", ["f", "v"]), ("en", ["F", "V"])])
def test_labiodental_targets_bring_the_lower_lip_to_the_teeth(language, symbols):
    for symbol in symbols:
        targets = phone_targets(symbol, language)
        assert targets["mouthRollLower"] >= 0.3 and targets["mouthUpperUpLeft"] <= 0.2
        assert aperture_of(targets) <= LIP_CLOSED


@pytest.mark.parametrize("language, open_vowels, rounded_vowels", [
    ("sv", ["A:", "a", "{:"], ["u:", "o:", "y:", "U"]),
    ("en", ["AA", "AE"], ["UW", "OW", "UH"]),
])
def test_vowel_targets(language, open_vowels, rounded_vowels):
    for symbol in open_vowels:
        for stress in (0, 1):
            assert 0.3 <= phone_targets(symbol, language, stress)["jawOpen"] <= 0.5
    for symbol in rounded_vowels:
        targets = phone_targets(symbol, language)
        assert targets["mouthPucker"] + targets["mouthFunnel"] >= 0.5
        assert targets["mouthSmileLeft"] == 0.0
    assert phone_targets(open_vowels[0], language, 1)["jawOpen"] > phone_targets(open_vowels[0], language, 0)["jawOpen"]


def test_silence_is_a_neutral_closed_mouth():
    for language in LANGUAGES:
        for symbol in ("sil", "sp"):
            targets = phone_targets(symbol, language)
            assert all(v == 0.0 for v in targets.values())


def test_undefined_channels():
    k = phone_targets("k", "sv")
    assert k["jawOpen"] is not None and k["mouthClose"] is None and k["mouthPucker"] is None
    assert all(v is None for c, v in phone_targets("HH", "en").items() if c != "tongueOut")
    assert phone_targets("W", "en")["mouthPucker"] >= 0.5  # a rounded consonant defines its rounding
    for language in LANGUAGES:
        values, defined = TargetTable().values(language), TargetTable().defined(language)
        vowel_rows = [i for i, s in enumerate(phone_rows(language).symbols) if s in get_inventory(language).vowels]
        assert defined[vowel_rows].all()
        assert ((values >= 0) & (values <= 1)).all()


def test_matrix_form_agrees_with_phone_targets():
    symbols, stresses = ["a", "m", "k", "i:"], [1, 0, 0, 2]
    values, defined = target_matrix(symbols, "sv", stresses)
    for row, (symbol, stress) in enumerate(zip(symbols, stresses)):
        targets = phone_targets(symbol, "sv", stress)
        for col, channel in enumerate(TARGET_CHANNELS):
            assert defined[row, col] == (targets[channel] is not None)
            if targets[channel] is not None:
                assert values[row, col] == targets[channel]


def test_overrides_apply_on_top():
    table = TargetTable({"sv": {"a": {"jawOpen": 0.9, "mouthSmile": None}}})
    row = phone_rows("sv").keys["a", True]
    jaw, smile = TARGET_CHANNELS.index("jawOpen"), TARGET_CHANNELS.index("mouthSmileRight")
    assert table.values("sv")[row, jaw] == 0.9 and not table.defined("sv")[row, smile]
    assert TargetTable().values("sv")[row, jaw] != 0.9
    for bad in ({"xx": {}}, {"sv": {"QQ": {"jawOpen": 0.1}}}, {"sv": {"a": {"noSuchChannel": 0.1}}},
                {"sv": {"a": {"jawOpen": 1.5}}}, [1], {"sv": [1]}, {"sv": {"a": 0.5}}):
        with pytest.raises(VispeechError):
            TargetTable(bad)
    with pytest.raises(VispeechError):
        phone_targets("QQ", "sv")


def test_resolve_spec_cascades_from_default_to_features_to_phones():
    spec = {"default": 1.0, "consonant": 2.0, "bilabial": {"mouthClose": 3.0}, "sv:m": 4.0}
    values = resolve_spec(spec, "sv", TARGET_CHANNELS)
    rows = phone_rows("sv")
    close = TARGET_CHANNELS.index("mouthClose")
    assert (values[rows.keys["a", False]] == 1.0).all()
    assert (values[rows.keys["t", False]] == 2.0).all()
    p = values[rows.keys["p", False]]
    assert p[close] == 3.0 and p[TARGET_CHANNELS.index("jawOpen")] == 2.0
    assert (values[rows.keys["m", True]] == 4.0).all()
    assert resolve_spec({"default": 0.5, "en:T": 1.0}, "sv").max() == 0.5  # other language's phones don't apply
    for bad in ({"vowel": 1.0}, {"default": "x"}, {"default": 1.0, "nonsense": 2.0}, {"default": {"jawOpen": 1.0}}):
        with pytest.raises(VispeechError):
            resolve_spec(bad, "sv", TARGET_CHANNELS)
    with pytest.raises(VispeechError):
        resolve_spec({"default": {"jawOpen": 1.0}}, "sv")


def test_lip_aperture_formula():
    channels = ("jawOpen", "mouthClose", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthRollLower")
    track = Track(np.array([[0.4, 0.1, 0.2, 0.2, 0.0], [0.1, 0.1, 0.0, 0.0, 0.2], [0.3, 0.0, 1.0, 1.0, 0.0]]), channels, 30)
    np.testing.assert_allclose(lip_aperture(track), [0.4 - 0.1 + 0.5 * 0.2, 0.0, 0.8])
    assert lip_aperture(Track.zeros(3, ("eyeBlinkLeft",), 30)).tolist() == [0.0, 0.0, 0.0]
