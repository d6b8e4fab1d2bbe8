"""Phone-to-viseme tables: the Oculus/Meta 15 visemes and Rhubarb Lip Sync's mouth shapes.

The tables live in ``data/visemes.tsv`` (one row per language and phone). English follows the
published OVRLipSync/OpenXR phoneme lists (``L`` -> ``nn`` as TalkingHead does) and the first
choice of Rhubarb's own animation rules (diphthongs take their onset shape). Swedish phones
take the viseme of their nearest English counterpart: front rounded and central rounded
vowels are ``ou``/``oh`` (``F``/``E``), retroflexes map like their alveolar partners
(``rs`` like ``SH``), the rounded sj-sound ``S`` is ``CH`` and puckered ``F``.
"""

from __future__ import annotations

import csv
from functools import cache
from importlib import resources

from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import get_inventory

OCULUS_VISEMES = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
"""The 15 Oculus/Meta visemes in OVRLipSync index order."""

RHUBARB_SHAPES = ("A", "B", "C", "D", "E", "F", "G", "H", "X")
"""Rhubarb mouth shapes: A closed (MBP), B slightly open, C open (E), D wide open (AI),
E rounded (O), F puckered (U, W), G F/V, H L, X rest."""


@cache
def _table() -> dict[tuple[str, str], tuple[str, str]]:
    """``{(language, symbol): (oculus viseme, rhubarb shape)}`` from ``data/visemes.tsv``."""
    text = resources.files("vispeech.phonetics").joinpath("data/visemes.tsv").read_text(encoding="utf-8")
    return {
        (row["language"], row["symbol"]): (row["oculus"], row["rhubarb"])
        for row in csv.DictReader(text.splitlines(), delimiter="\t")
    }


def _lookup(symbol: str, language: str) -> tuple[str, str]:
    get_inventory(language)
    try:
        return _table()[language, symbol]
    except KeyError:
        raise VispeechError(f"unknown phone symbol {symbol!r} for language {language}") from None


def oculus_viseme(symbol: str, language: str) -> str:
    """The Oculus viseme (one of :data:`OCULUS_VISEMES`) of an inventory symbol."""
    return _lookup(symbol, language)[0]


def rhubarb_shape(symbol: str, language: str) -> str:
    """The Rhubarb mouth shape (one of :data:`RHUBARB_SHAPES`) of an inventory symbol."""
    return _lookup(symbol, language)[1]
