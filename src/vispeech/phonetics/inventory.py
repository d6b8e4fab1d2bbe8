"""Phone inventories.

Every phone sequence in vispeech uses one symbol set per language: Swedish in the thesis's
MFA-style ASCII set, English in ARPAbet (stress kept apart from the symbol, see
:class:`vispeech.alignment.phones.Phone`). Both share the silence symbols below.
"""

SILENCE = "sil"
"""Silence: leading, trailing and long pauses."""

PAUSE = "sp"
"""A short pause between words."""

SILENCE_SYMBOLS = frozenset({SILENCE, PAUSE})


def is_silence(symbol: str) -> bool:
    """True for the silence and short-pause symbols."""
    return symbol in SILENCE_SYMBOLS
