"""Articulatory feature vectors for the phones of every inventory.

The first 17 features are Beskow's (2004) ANN input: consonant/vowel, six places, five
manners, four three-valued vowel features (0, 0.5, 1) and stress. The extras after them
(other places, laterality, approximants, diphthongs, open-mid height, length, silence,
pause) tell apart the phones both languages have, so one vector space serves Swedish and
English alike: a model trained on English features can drive Swedish phones.

The values of the curated inventories live in ``data/features.tsv`` (one row per language and
phone; every column but ``stress``, which comes from the phone); those of IPA phones come from
the IPA itself (:func:`vispeech.phonetics.ipa.ipa_features`). Conventions: vowels are ``voiced``; diphthongs carry
their onset quality (``AW`` with half rounding for its rounded glide); lip rounding and
protrusion are also set for rounded consonants (``W``, ``SH``-like, Swedish ``S``);
``release`` is kept for Beskow's stop-release symbols, which neither inventory has.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cache
from importlib import resources

import numpy as np

from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import IPA, LANGUAGES, PAUSE, get_inventory, is_silence, is_vowel
from vispeech.phonetics.ipa import ipa_features

FEATURE_NAMES: tuple[str, ...] = (
    # Beskow (2004), in his order
    "vowel",
    "bilabial",
    "labiodental",
    "dental",
    "alveolar",
    "retroflex",
    "velar",
    "nasal",
    "fricative",
    "stop",
    "release",
    "voiced",
    "open",
    "front",
    "rounded",
    "protruded",
    "stress",
    # extras that tell apart the phones of both inventories
    "postalveolar",
    "palatal",
    "glottal",
    "lateral",
    "approximant",
    "diphthong",
    "open_mid",
    "long",
    "silence",
    "pause",
)
"""Names of the feature vector's entries, in order."""

_STRESS = FEATURE_NAMES.index("stress")


@cache
def _curated() -> dict[str, dict[str, np.ndarray]]:
    """``{language: {symbol: vector with stress 0}}`` read from ``data/features.tsv``."""
    text = resources.files("vispeech.phonetics").joinpath("data/features.tsv").read_text(encoding="utf-8")
    rows = csv.DictReader(text.splitlines(), delimiter="\t")
    table: dict[str, dict[str, np.ndarray]] = {}
    for row in rows:
        vector = np.array([0.0 if name == "stress" else float(row[name]) for name in FEATURE_NAMES])
        vector.setflags(write=False)
        table.setdefault(row["language"], {})[row["symbol"]] = vector
    return table


@cache
def _ipa() -> dict[str, np.ndarray]:
    """``{symbol: vector with stress 0}`` of every IPA phone, silences included."""
    table: dict[str, np.ndarray] = {}
    for symbol in get_inventory(IPA).symbols:
        if is_silence(symbol):
            features = {"silence": 1.0, "pause": float(symbol == PAUSE)}
        else:
            features = ipa_features(symbol)
        vector = np.array([features.get(name, 0.0) for name in FEATURE_NAMES])
        vector.setflags(write=False)
        table[symbol] = vector
    return table


def _table(language: str) -> dict[str, np.ndarray]:
    """``{symbol: vector with stress 0}`` of one phone set."""
    return _ipa() if language == IPA else _curated()[language]


def phone_features(symbol: str, language: str, stress: int = 0) -> np.ndarray:
    """Feature vector (float64, ``len(FEATURE_NAMES)``) of an inventory symbol.

    ``stress`` (1 or 2 = stressed) sets the ``stress`` feature of vowels to 1.
    """
    get_inventory(language)
    try:
        vector = _table(language)[symbol].copy()
    except KeyError:
        raise VispeechError(f"unknown phone symbol {symbol!r} for language {language}") from None
    if stress and is_vowel(symbol, language):
        vector[_STRESS] = 1.0
    return vector


@cache
def feature_table(language: str) -> tuple[tuple[str, ...], np.ndarray]:
    """``(symbols, matrix)``: every inventory symbol and its unstressed feature row (read-only)."""
    symbols = get_inventory(language).symbols
    matrix = np.stack([_table(language)[s] for s in symbols])
    matrix.setflags(write=False)
    return symbols, matrix


@dataclass(frozen=True)
class PhoneRows:
    """Every phone of one language twice, unstressed and stressed, with its feature vector.

    ``keys[(symbol, stressed)]`` is the row of a phone; tables over a language (targets,
    resolved specs) are arrays with one row per key.
    """

    language: str
    keys: Mapping[tuple[str, bool], int]
    symbols: tuple[str, ...]
    features: np.ndarray

    def indices(self, symbols: Iterable[str], stresses: Iterable[int]) -> np.ndarray:
        """Row of each (symbol, stress); raises :class:`VispeechError` on an unknown symbol."""
        keys = self.keys
        try:
            return np.array([keys[s, t > 0] for s, t in zip(symbols, stresses)], dtype=np.intp)
        except KeyError as exc:
            symbol = exc.args[0][0]
            raise VispeechError(f"unknown phone symbol {symbol!r} for language {self.language}") from None

    def mask(self, key: str) -> np.ndarray:
        """Rows a spec key selects: a class key, a feature name or ``<language>:<symbol>``."""
        if key == "default":
            return np.ones(len(self.symbols), dtype=bool)
        if key == "consonant":
            f = self.features
            return (f[:, FEATURE_NAMES.index("vowel")] == 0) & (f[:, FEATURE_NAMES.index("silence")] == 0)
        if key in FEATURE_NAMES:
            return self.features[:, FEATURE_NAMES.index(key)] > 0
        language, sep, symbol = key.partition(":")
        if sep and language in LANGUAGES and symbol in get_inventory(language).symbols:
            return np.array([language == self.language and s == symbol for s in self.symbols])
        raise VispeechError(
            f"unknown phone key {key!r} (use default, consonant, a feature name or <language>:<symbol>)"
        )


@cache
def phone_rows(language: str) -> PhoneRows:
    """The :class:`PhoneRows` of ``language``."""
    symbols = get_inventory(language).symbols
    keys: dict[tuple[str, bool], int] = {}
    rows: list[str] = []
    features: list[np.ndarray] = []
    for symbol in symbols:
        for stressed in (False, True):
            keys[symbol, stressed] = len(rows)
            rows.append(symbol)
            features.append(phone_features(symbol, language, int(stressed)))
    matrix = np.array(features)
    matrix.setflags(write=False)
    return PhoneRows(language, keys, tuple(rows), matrix)
