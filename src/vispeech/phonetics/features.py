"""Articulatory feature vectors for the phones of every inventory.

The first 17 features are Beskow's (2004) ANN input: consonant/vowel, six places, five
manners, four three-valued vowel features (0, 0.5, 1) and stress. The extras after them
(other places, laterality, approximants, diphthongs, open-mid height, length, silence,
pause) tell apart the phones both languages have, so one vector space serves Swedish and
English alike: a model trained on English features can drive Swedish phones.

The values live in ``data/features.tsv`` (one row per language and phone; every column but
``stress``, which comes from the phone). Conventions: vowels are ``voiced``; diphthongs carry
their onset quality (``AW`` with half rounding for its rounded glide); lip rounding and
protrusion are also set for rounded consonants (``W``, ``SH``-like, Swedish ``S``);
``release`` is kept for Beskow's stop-release symbols, which neither inventory has.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from functools import cache
from importlib import resources

import numpy as np

from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import get_inventory, is_vowel

FEATURE_NAMES: tuple[str, ...] = (
    # Beskow (2004), in his order
    "vowel",
    "bilabial", "labiodental", "dental", "alveolar", "retroflex", "velar",
    "nasal", "fricative", "stop", "release", "voiced",
    "open", "front", "rounded", "protruded",
    "stress",
    # extras that tell apart the phones of both inventories
    "postalveolar", "palatal", "glottal", "lateral", "approximant",
    "diphthong", "open_mid", "long", "silence", "pause",
)
"""Names of the feature vector's entries, in order."""

_STRESS = FEATURE_NAMES.index("stress")


@cache
def _table() -> dict[str, dict[str, np.ndarray]]:
    """``{language: {symbol: vector with stress 0}}`` read from ``data/features.tsv``."""
    text = resources.files("vispeech.phonetics").joinpath("data/features.tsv").read_text(encoding="utf-8")
    rows = csv.DictReader(text.splitlines(), delimiter="\t")
    table: dict[str, dict[str, np.ndarray]] = {}
    for row in rows:
        vector = np.array([0.0 if name == "stress" else float(row[name]) for name in FEATURE_NAMES])
        vector.setflags(write=False)
        table.setdefault(row["language"], {})[row["symbol"]] = vector
    return table


def phone_features(symbol: str, language: str, stress: int = 0) -> np.ndarray:
    """Feature vector (float64, ``len(FEATURE_NAMES)``) of an inventory symbol.

    ``stress`` (1 or 2 = stressed) sets the ``stress`` feature of vowels to 1.
    """
    get_inventory(language)
    try:
        vector = _table()[language][symbol].copy()
    except KeyError:
        raise VispeechError(f"unknown phone symbol {symbol!r} for language {language}") from None
    if stress and is_vowel(symbol, language):
        vector[_STRESS] = 1.0
    return vector


@cache
def feature_table(language: str) -> tuple[tuple[str, ...], np.ndarray]:
    """``(symbols, matrix)``: every inventory symbol and its unstressed feature row (read-only)."""
    symbols = get_inventory(language).symbols
    matrix = np.stack([_table()[language][s] for s in symbols])
    matrix.setflags(write=False)
    return symbols, matrix


@cache
def _rows(language: str) -> tuple[dict[tuple[str, bool], int], np.ndarray]:
    """Every symbol of ``language`` unstressed and stressed: ``({(symbol, stressed): row}, matrix)``."""
    symbols, matrix = feature_table(language)
    stressed = matrix.copy()
    stressed[[i for i, s in enumerate(symbols) if is_vowel(s, language)], _STRESS] = 1.0
    keys = {(s, False): i for i, s in enumerate(symbols)} | {(s, True): len(symbols) + i for i, s in enumerate(symbols)}
    both = np.concatenate([matrix, stressed])
    both.setflags(write=False)
    return keys, both


def feature_rows(symbols: Iterable[str], language: str, stresses: Iterable[int]) -> np.ndarray:
    """The feature vectors of many phones at once (phones × ``len(FEATURE_NAMES)``), as
    :func:`phone_features` gives each."""
    get_inventory(language)
    keys, matrix = _rows(language)
    try:
        return matrix[[keys[s, bool(t)] for s, t in zip(symbols, stresses)]]
    except KeyError as exc:
        raise VispeechError(f"unknown phone symbol {exc.args[0][0]!r} for language {language}") from None
