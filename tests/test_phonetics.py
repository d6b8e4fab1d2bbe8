import re

import numpy as np
import pytest

from vispeech.errors import VispeechError
from vispeech.phonetics.features import FEATURE_NAMES, feature_table, phone_features
from vispeech.phonetics.inventory import (
    LANGUAGES,
    PAUSE,
    SILENCE,
    get_inventory,
    guess_language,
    is_silence,
    is_vowel,
    parse_symbol,
)

BESKOW_17 = (
    "vowel", "bilabial", "labiodental", "dental", "alveolar", "retroflex", "velar",
    "nasal", "fricative", "stop", "release", "voiced", "open", "front", "rounded", "protruded", "stress",
)


def f(symbol, language, name, stress=0):
    return phone_features(symbol, language, stress)[FEATURE_NAMES.index(name)]


def test_inventories():
    sv, en = get_inventory("sv"), get_inventory("en")
    assert LANGUAGES == ("sv", "en", "ipa")
    assert len(sv.symbols) == 47 and len(set(sv.symbols)) == 47
    assert len(en.symbols) == 41 and len(set(en.symbols)) == 41
    for inv in (sv, en):
        assert SILENCE in inv.symbols and PAUSE in inv.symbols
        assert inv.vowels < set(inv.symbols)
    assert {"i:", "I", "u0", "}:", "9:", "A:", "a", "@"} <= sv.vowels
    assert {"S", "C", "rt", "rd", "rn", "rs", "rl", "N"} <= set(sv.symbols) - sv.vowels
    assert len(sv.vowels) == 22 and len(en.vowels) == 15
    assert is_vowel("ER", "en") and not is_vowel("R", "en") and not is_vowel("sil", "sv")
    with pytest.raises(VispeechError, match=r"unknown language 'xx' for phones \(use sv, en or ipa\)"):
        get_inventory("xx")


@pytest.mark.parametrize(
    ("label", "language", "expected"),
    [
        ("AA1", "en", ("AA", 1)),
        ("aa0", "en", ("AA", 0)),
        ("ng", "en", ("NG", 0)),
        ("Er2", "en", ("ER", 2)),
        ("TH", "en", ("TH", 0)),
        ("sil", "en", ("sil", 0)),
        ("SIL", "sv", ("sil", 0)),
        ("spn", "en", ("sil", 0)),
        ("<eps>", "sv", ("sil", 0)),
        ("", "en", ("sil", 0)),
        ("_", "sv", ("sil", 0)),
        ("sp", "sv", ("sp", 0)),
        ("SP", "en", ("sp", 0)),
        ("A:", "sv", ("A:", 0)),
        ("'A:", "sv", ("A:", 1)),
        ('"u0', "sv", ("u0", 2)),
        ("rs", "sv", ("rs", 0)),
        ("E", "sv", ("E", 0)),
        ("e", "sv", ("e", 0)),
    ],
)
def test_parse_symbol(label, language, expected):
    assert parse_symbol(label, language) == expected


@pytest.mark.parametrize(
    ("label", "language"),
    [("Q", "en"), ("AA3", "en"), ("A:", "en"), ("aa", "sv"), ("SH", "sv"), ("'", "sv"), ("1", "en")],
)
def test_parse_symbol_unknown(label, language):
    message = f"unknown phone symbol {label!r} for language {language}"
    with pytest.raises(VispeechError, match=re.escape(message)):
        parse_symbol(label, language)


def test_parse_symbol_unknown_language():
    with pytest.raises(VispeechError, match="unknown language"):
        parse_symbol("AA", "de")


def test_guess_language():
    assert guess_language(["sil", "HH", "AH0", "L", "OW1", "sp", "SIL"]) == "en"
    assert guess_language(["sil", "h", "'E", "j", "sp", "v", "i:", "m", '"9:', "t", "s"]) == "sv"
    assert guess_language(iter(["b", "A:", "rn"])) == "sv"
    with pytest.raises(VispeechError, match="'Q'"):
        guess_language(["sil", "h", "E", "Q", "AA1", "Z"])
    with pytest.raises(VispeechError, match="'AA1'"):  # mixed: known in one language each
        guess_language(["h", "E:", "AA1"])


@pytest.mark.parametrize("language", LANGUAGES)
def test_every_symbol_has_features(language):
    symbols, matrix = feature_table(language)
    assert symbols == get_inventory(language).symbols
    assert matrix.shape == (len(symbols), len(FEATURE_NAMES)) and matrix.dtype == np.float64
    assert set(np.unique(matrix)) <= {0.0, 0.5, 1.0}
    # every curated phone has its own vector, so no two phones look alike to a model (IPA
    # phones may share one: diacritics the face does not show are dropped, clicks are stops)
    if language != "ipa":
        assert len({tuple(row) for row in matrix}) == len(symbols)
    for symbol, row in zip(symbols, matrix):
        np.testing.assert_array_equal(phone_features(symbol, language), row)
        assert row[FEATURE_NAMES.index("vowel")] == is_vowel(symbol, language)
        assert row[FEATURE_NAMES.index("silence")] == is_silence(symbol)


def test_feature_names_start_with_beskow():
    assert FEATURE_NAMES[:17] == BESKOW_17
    assert len(set(FEATURE_NAMES)) == len(FEATURE_NAMES)
    assert {"silence", "long", "postalveolar", "lateral"} <= set(FEATURE_NAMES)


def test_features_distinguish_places():
    places = {
        "bilabial": [("p", "sv"), ("b", "sv"), ("m", "sv"), ("P", "en"), ("B", "en"), ("M", "en")],
        "labiodental": [("f", "sv"), ("v", "sv"), ("F", "en"), ("V", "en")],
        "dental": [("TH", "en"), ("DH", "en")],
        "alveolar": [("t", "sv"), ("s", "sv"), ("T", "en"), ("S", "en"), ("N", "en")],
        "retroflex": [("rt", "sv"), ("rd", "sv"), ("rn", "sv"), ("rs", "sv"), ("rl", "sv")],
        "velar": [("k", "sv"), ("N", "sv"), ("K", "en"), ("NG", "en")],
    }
    for place, phones in places.items():
        for symbol, language in phones:
            vector = phone_features(symbol, language)
            on = [name for name in places if vector[FEATURE_NAMES.index(name)] == 1]
            assert on == [place], (symbol, language, on)
    # same-place phones differ in manner or voicing
    assert not np.array_equal(phone_features("p", "sv"), phone_features("b", "sv"))
    assert not np.array_equal(phone_features("b", "sv"), phone_features("m", "sv"))


def test_features_agree_across_languages():
    # the shared phones have the same vector in both languages
    for sv, en in [("p", "P"), ("b", "B"), ("m", "M"), ("f", "F"), ("v", "V"), ("k", "K"), ("g", "G"),
                   ("t", "T"), ("d", "D"), ("s", "S"), ("l", "L"), ("N", "NG"), ("h", "HH"), ("j", "Y"),
                   ("i:", "IY"), ("I", "IH"), ("A:", "AA"), ("u:", "UW"), ("sil", "sil"), ("sp", "sp")]:
        np.testing.assert_array_equal(phone_features(sv, "sv"), phone_features(en, "en"), err_msg=sv)


def test_vowel_features():
    assert f("A:", "sv", "open") == 1 and f("i:", "sv", "open") == 0 and f("e:", "sv", "open") == 0.5
    assert f("i:", "sv", "front") == 1 and f("u:", "sv", "front") == 0 and f("}:", "sv", "front") == 0.5
    assert f("y:", "sv", "rounded") == 1 and f("i:", "sv", "rounded") == 0
    assert f("UW", "en", "protruded") == 1 and f("IY", "en", "protruded") == 0
    assert f("i:", "sv", "long") == 1 and f("I", "sv", "long") == 0
    assert f("E:", "sv", "open_mid") == 1 and f("e:", "sv", "open_mid") == 0


def test_stress_feature():
    assert f("AA", "en", "stress", 1) == 1 and f("AA", "en", "stress", 0) == 0
    assert f("A:", "sv", "stress", 2) == 1
    assert f("P", "en", "stress", 1) == 0  # consonants carry no stress
    # the rest of the vector is unchanged
    a, b = phone_features("AA", "en", 1), phone_features("AA", "en", 0)
    assert np.flatnonzero(a != b).tolist() == [FEATURE_NAMES.index("stress")]


def test_silence_features():
    sil, sp = phone_features("sil", "en"), phone_features("sp", "en")
    assert sil[FEATURE_NAMES.index("silence")] == 1 and sp[FEATURE_NAMES.index("silence")] == 1
    assert sil.sum() == 1 and sp[FEATURE_NAMES.index("pause")] == 1


def test_feature_errors():
    with pytest.raises(VispeechError, match="unknown phone symbol 'AA1' for language en"):
        phone_features("AA1", "en")
    with pytest.raises(VispeechError, match="unknown language"):
        feature_table("de")
    with pytest.raises(VispeechError, match="unknown phone symbol 'AA' for language sv"):
        phone_features("AA", "sv")


def test_feature_table_is_read_only_and_copies_are_safe():
    _, matrix = feature_table("sv")
    with pytest.raises(ValueError):
        matrix[0, 0] = 5
    vector = phone_features("a", "sv")
    vector[:] = 9
    assert phone_features("a", "sv").max() == 1
