"""IPA phones: segmentation, hand-checked articulatory features, the curated sets' agreement,
espeak-ng's IPA names, alignment files and JSON in IPA (issue 14), and the shipped PanPhon
table, which must be what the panphon package holds (issue 25)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import DATA
from panphon_table import TABLE, table_text
from vispeech.alignment.formats import read_alignment, write_textgrid
from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.phonetics.espeak_names import espeak_ipa_to_symbols
from vispeech.phonetics.features import FEATURE_NAMES, phone_features
from vispeech.phonetics.inventory import get_inventory, guess_language, parse_symbol
from vispeech.phonetics.ipa import parse_ipa, split_ipa


def _hand_checked() -> list[tuple[str, dict[str, float]]]:
    rows = []
    for line in (DATA / "ipa_features.tsv").read_text(encoding="utf-8").splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        label, features = line.split("\t")
        expected = {}
        for item in features.split():
            name, _, value = item.partition("=")
            expected[name] = float(value) if value else 1.0
        rows.append((label, expected))
    return rows


HAND_CHECKED = _hand_checked()


def test_at_least_sixty_segments_are_hand_checked():
    assert len({parse_symbol(label, "ipa")[0] for label, _ in HAND_CHECKED}) >= 60


@pytest.mark.parametrize(("label", "expected"), HAND_CHECKED, ids=[label for label, _ in HAND_CHECKED])
def test_features_of_hand_checked_segments(label, expected):
    assert set(expected) <= set(FEATURE_NAMES)
    symbol, _ = parse_symbol(label, "ipa")
    want = np.array([expected.get(name, 0.0) for name in FEATURE_NAMES])
    got = phone_features(symbol, "ipa")
    differ = {FEATURE_NAMES[i]: (got[i], want[i]) for i in np.flatnonzero(got != want)}
    assert not differ, f"{label} ({symbol}): got, expected: {differ}"


# IPA for the curated symbols: the IPA reading gives the curated row exactly. Left out, where
# the curated rows follow the language rather than the chart: English R (postalveolar, IPA ɹ
# is alveolar), AH (ʌ is back, not open-mid in PanPhon), UH (half protruded), ER (long).
SAME_AS_CURATED = {
    "sv": {"i:": "iː", "I": "ɪ", "y:": "yː", "Y": "ʏ", "e:": "eː", "e": "e", "E:": "ɛː", "E": "ɛ", "{:": "æː",
           "{": "æ", "2:": "øː", "9:": "œː", "9": "œ", "}:": "ʉː", "u0": "ɵ", "u:": "uː", "U": "ʊ", "o:": "oː",
           "O": "ɔ", "A:": "ɑː", "a": "a", "@": "ə", "p": "p", "b": "b", "t": "t", "d": "d", "k": "k", "g": "ɡ",
           "m": "m", "n": "n", "N": "ŋ", "f": "f", "v": "v", "s": "s", "S": "ɧ", "C": "ɕ", "h": "h", "j": "j",
           "l": "l", "r": "r", "rt": "ʈ", "rd": "ɖ", "rn": "ɳ", "rs": "ʂ", "rl": "ɭ"},
    "en": {"AA": "ɑː", "AE": "æ", "AO": "ɔː", "AW": "aʊ", "AY": "aɪ", "EH": "ɛ", "EY": "eɪ", "IH": "ɪ", "IY": "iː",
           "OW": "oʊ", "OY": "ɔɪ", "UW": "uː", "B": "b", "CH": "tʃ", "D": "d", "DH": "ð", "F": "f", "G": "ɡ",
           "HH": "h", "JH": "dʒ", "K": "k", "L": "l", "M": "m", "N": "n", "NG": "ŋ", "P": "p", "S": "s",
           "SH": "ʃ", "T": "t", "TH": "θ", "V": "v", "W": "w", "Y": "j", "Z": "z", "ZH": "ʒ"},
}


@pytest.mark.parametrize("language", ["sv", "en"])
def test_ipa_reading_of_curated_phones_matches_their_rows(language):
    pairs = SAME_AS_CURATED[language]
    curated = set(get_inventory(language).symbols) - {"sil", "sp"}
    assert len(pairs) >= len(curated) - 4
    for symbol, ipa in pairs.items():
        np.testing.assert_array_equal(phone_features(parse_ipa(ipa)[0], "ipa"), phone_features(symbol, language),
                                      err_msg=f"{language} {symbol} vs IPA {ipa}")


def test_every_ipa_symbol_reads_as_itself():
    inventory = get_inventory("ipa")
    assert len(inventory.symbols) > 1000
    for symbol in inventory.symbols:
        assert parse_symbol(symbol, "ipa") == (symbol, 0), symbol


def test_split_and_stress():
    assert split_ipa("ˈʔo") == [("ʔ", 0), ("o", 1)]  # Danish stød before a stressed vowel
    assert split_ipa("ˌaɪ̯ə") == [("aɪ", 2), ("ə", 0)]
    assert split_ipa("t͡ʃˈaː") == [("tʃ", 0), ("aː", 1)]
    assert parse_ipa("ˈa:") == ("aː", 1)  # an ASCII colon is a length mark
    assert parse_ipa("kʰʷ") == ("kʷ", 0)


@pytest.mark.parametrize(("label", "message"), [
    ("a#", r"IPA 'a#': '#' at position 1 is not an IPA segment"),
    ("ː", r"'ː' at position 0 modifies no segment"),
    ("ta", r"holds 2 segments \(t a\)"),
    ("ʰ", "holds no segment"),
])
def test_parse_errors_name_symbol_and_position(label, message):
    with pytest.raises(VispeechError, match=message):
        parse_symbol(label, "ipa")


@pytest.mark.parametrize(("name", "expected"), [
    ("ˈuː", (("uː", 1),)), ("", (("sil", 0),)), ("ʔo", (("ʔ", 0), ("o", 0))), ("ː", ()),
    ("tS", (("tʃ", 0),)), ("dZ", (("dʒ", 0),)), ("t[", (("t̪", 0),)), ("n^", (("ɲ", 0),)), ("s.", (("ʂ", 0),)),
    ("y-", (("y", 0),)), ("r#", (("r", 0),)), ("ˈA", (("ɑ", 1),)), ("ˈɯᵝ", (("ɯ", 1),)),
])
def test_espeak_ipa_names(name, expected):
    assert espeak_ipa_to_symbols(name) == expected


def test_guess_language_reads_ipa_labels():
    assert guess_language(["sil", "h", "ɛ", "l", "oʊ", "sp"]) == "ipa"
    assert guess_language(["m", "a", "t"]) == "sv"  # Swedish symbols are read as Swedish
    with pytest.raises(VispeechError, match=r"unknown phone symbol 'Q#' \(phone 2\)"):
        guess_language(["h", "ɛ", "Q#"])
    # a file's reader gives the times: docs/formats.md promises the label, its position and time
    with pytest.raises(VispeechError, match=r"unknown phone symbol 'Q#' \(phone 2 at 0.250 s\): neither"):
        guess_language(["h", "ɛ", "Q#"], [0.0, 0.1, 0.25])


_MFA_TEXTGRID = """File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 1.0
tiers? <exists>
size = 2
item []:
    item [1]:
        class = "IntervalTier"
        name = "words"
        xmin = 0
        xmax = 1.0
        intervals: size = 2
        intervals [1]:
            xmin = 0
            xmax = 0.1
            text = ""
        intervals [2]:
            xmin = 0.1
            xmax = 1.0
            text = "maybe"
    item [2]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 1.0
        intervals: size = 6
        intervals [1]:
            xmin = 0
            xmax = 0.1
            text = ""
        intervals [2]:
            xmin = 0.1
            xmax = 0.25
            text = "m"
        intervals [3]:
            xmin = 0.25
            xmax = 0.5
            text = "ej"
        intervals [4]:
            xmin = 0.5
            xmax = 0.6
            text = "{b}"
        intervals [5]:
            xmin = 0.6
            xmax = 0.9
            text = "iː"
        intervals [6]:
            xmin = 0.9
            xmax = 1.0
            text = "tʰ"
"""


def test_textgrid_with_an_ipa_tier(tmp_path):
    path = tmp_path / "maybe.TextGrid"
    path.write_text(_MFA_TEXTGRID.replace("{b}", "b"), encoding="utf-8")
    phones = read_alignment(path)
    assert phones.language == "ipa"
    assert phones.symbols == ["sil", "m", "ei", "b", "iː", "t"]
    assert [w.text for w in phones.words] == ["maybe"]
    # written back with IPA stress marks, it reads the same
    stressed = PhoneSequence([*phones.phones[:2], Phone("ei", 0.25, 0.5, 0, 1), *phones.phones[3:]], "ipa",
                             phones.words)
    out = tmp_path / "out.TextGrid"
    write_textgrid(stressed, out)
    assert "ˈei" in out.read_text(encoding="utf-8")
    again = read_alignment(out)
    assert again.symbols == stressed.symbols and [p.stress for p in again] == [p.stress for p in stressed]


def test_textgrid_error_names_the_phone_and_its_time(tmp_path):
    path = tmp_path / "bad.TextGrid"
    path.write_text(_MFA_TEXTGRID.replace("{b}", "b#"), encoding="utf-8")
    with pytest.raises(VispeechError, match=r"bad\.TextGrid: phone 3 at 0\.500 s: .*'#' at position 1"):
        read_alignment(path, "ipa")


def test_json_phones_in_ipa_read_as_segments(tmp_path):
    path = tmp_path / "phones.json"
    data = {"format": "vispeech-phones", "version": 1, "language": "ipa", "words": [],
            "phones": [{"symbol": "sil", "start": 0.0, "end": 0.1}, {"symbol": "t͡ʃ", "start": 0.1, "end": 0.2},
                       {"symbol": "ˈaɪ̯", "start": 0.2, "end": 0.5}, {"symbol": "sil", "start": 0.5, "end": 0.6}]}
    path.write_text(json.dumps(data, ensure_ascii=False), encoding="utf-8")
    phones = read_alignment(path)
    assert phones.symbols == ["sil", "tʃ", "aɪ", "sil"] and [p.stress for p in phones] == [0, 0, 1, 0]
    data["phones"][2]["symbol"] = "a+"
    path.write_text(json.dumps(data, ensure_ascii=False), encoding="utf-8")
    with pytest.raises(VispeechError, match=r"phone 2 at 0\.200 s: .*'\+' at position 1"):
        read_alignment(path)


def test_the_shipped_panphon_table_is_panphons():
    """data/panphon.tsv is what tests/panphon_table.py writes from the installed panphon (the
    test extra): PanPhon's rows, credit and licence, unedited."""
    shipped = TABLE.read_text(encoding="utf-8")
    assert shipped == table_text(), "run python tests/panphon_table.py"
    assert shipped.startswith("# PanPhon ") and "# Permission is hereby granted" in shipped
