"""Phone inventories.

Every phone sequence in vispeech uses one of three symbol sets, named by its ``language``:
Swedish (``sv``) in the thesis's MFA-style ASCII set, English (``en``) in ARPAbet, and IPA
(``ipa``) for every other language espeak-ng speaks, and for any transcription in IPA (see
:mod:`vispeech.phonetics.ipa`). Stress is kept apart from the symbol (see
:class:`vispeech.alignment.phones.Phone`). All three share the silence symbols below.

Swedish (47 symbols, X-SAMPA-like as the NST lexicon writes them; example words in brackets):

===========  ========================================================================
long vowels  ``i:`` [bil], ``y:`` [syl], ``e:`` [hel], ``E:`` ɛː [häl], ``{:`` æː [här],
             ``2:`` øː [föl], ``9:`` œː [för], ``}:`` ʉː [hus], ``u:`` [bo], ``o:`` [båt],
             ``A:`` ɑː [mat]
short        ``I`` ɪ [sill], ``Y`` ʏ [syll], ``e`` [vett], ``E`` ɛ [rätt], ``{`` æ [ärr],
vowels       ``9`` œ [förr], ``u0`` ɵ [hund], ``U`` ʊ [bott], ``O`` ɔ [moll], ``a`` [matt],
             ``@`` ə [pojken]
consonants   ``p b t d k g m n f v s h j l r``, ``N`` ŋ [ring], ``S`` ɧ [sjal],
             ``C`` ɕ [tjog]
retroflexes  ``rt`` ʈ [kort], ``rd`` ɖ [bord], ``rn`` ɳ [barn], ``rs`` ʂ [fors], ``rl`` ɭ [karl]
silence      ``sil``, ``sp``
===========  ========================================================================

Swedish labels may carry a leading stress mark: ``'`` (stress 1, accent 1) or ``"``
(stress 2, accent 2). English is the 39-phone ARPAbet set (plus ``sil``, ``sp``); its labels
may carry a stress digit 0, 1 or 2 (``AA1``) and may be in any case.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cache, lru_cache

from vispeech.errors import VispeechError
from vispeech.phonetics.ipa import ipa_symbols, parse_ipa

SILENCE = "sil"
"""Silence: leading, trailing and long pauses."""

PAUSE = "sp"
"""A short pause between words."""

SILENCE_SYMBOLS = frozenset({SILENCE, PAUSE})

IPA = "ipa"
"""The phone set of every language without a curated inventory: IPA segments."""

LANGUAGES = ("sv", "en", IPA)
"""The phone sets: Swedish and (American) English, curated; IPA, for any language."""

_SILENCE_LABELS = frozenset({"sil", "spn", "<eps>", "", "_"})  # compared lower-case; "sp" is PAUSE
_SWEDISH_STRESS_MARKS = {"'": 1, '"': 2}


def is_silence(symbol: str) -> bool:
    """True for the silence and short-pause symbols."""
    return symbol in SILENCE_SYMBOLS


@dataclass(frozen=True)
class Inventory:
    """The phone symbols of one language; ``symbols`` include ``sil`` and ``sp``."""

    language: str
    symbols: tuple[str, ...]
    vowels: frozenset[str]


_SV_VOWELS = (
    "i:",
    "I",
    "y:",
    "Y",
    "e:",
    "e",
    "E:",
    "E",
    "{:",
    "{",
    "2:",
    "9:",
    "9",
    "}:",
    "u0",
    "u:",
    "U",
    "o:",
    "O",
    "A:",
    "a",
    "@",
)
_SV_CONSONANTS = (
    "p",
    "b",
    "t",
    "d",
    "k",
    "g",
    "m",
    "n",
    "N",
    "f",
    "v",
    "s",
    "S",
    "C",
    "h",
    "j",
    "l",
    "r",
    "rt",
    "rd",
    "rn",
    "rs",
    "rl",
)
_EN_VOWELS = ("AA", "AE", "AH", "AO", "AW", "AY", "EH", "ER", "EY", "IH", "IY", "OW", "OY", "UH", "UW")
_EN_CONSONANTS = (
    "B",
    "CH",
    "D",
    "DH",
    "F",
    "G",
    "HH",
    "JH",
    "K",
    "L",
    "M",
    "N",
    "NG",
    "P",
    "R",
    "S",
    "SH",
    "T",
    "TH",
    "V",
    "W",
    "Y",
    "Z",
    "ZH",
)

_INVENTORIES = {
    "sv": Inventory("sv", _SV_VOWELS + _SV_CONSONANTS + (SILENCE, PAUSE), frozenset(_SV_VOWELS)),
    "en": Inventory("en", _EN_VOWELS + _EN_CONSONANTS + (SILENCE, PAUSE), frozenset(_EN_VOWELS)),
}


def get_inventory(language: str) -> Inventory:
    """The inventory of ``language`` (``"sv"``, ``"en"`` or ``"ipa"``)."""
    if language == IPA:
        return _ipa_inventory()
    try:
        return _INVENTORIES[language]
    except (KeyError, TypeError):
        raise VispeechError(f"unknown language {language!r} for phones (use sv, en or ipa)") from None


@cache
def _ipa_inventory() -> Inventory:
    symbols, vowels = ipa_symbols()
    return Inventory(IPA, symbols + (SILENCE, PAUSE), vowels)


def parse_symbol(label: str, language: str) -> tuple[str, int]:
    """Turn a label as found in alignment files into ``(inventory symbol, stress)``.

    ``sil``, ``SIL``, ``spn``, ``<eps>``, ``_`` and the empty label read as ``sil``, ``sp``
    as ``sp`` (any case). English takes ARPAbet in any case with an optional stress digit
    (``AA1`` -> ``("AA", 1)``); Swedish takes its symbols with an optional leading stress
    mark ``'`` (1) or ``"`` (2); IPA takes one segment (:func:`~vispeech.phonetics.ipa.parse_ipa`:
    ``ˈaː`` -> ``("aː", 1)``, diacritics that the face does not show dropped).
    """
    get_inventory(language)  # an unknown language is an error, whatever the label
    return _parse_symbol(label, language)


@lru_cache(maxsize=4096)
def _parse_symbol(label: str, language: str) -> tuple[str, int]:
    """:func:`parse_symbol` (labels recur: every alignment file repeats the same few dozen)."""
    inventory = get_inventory(language)
    text = label.strip()
    folded = text.lower()
    if folded == PAUSE:
        return PAUSE, 0
    if folded in _SILENCE_LABELS:
        return SILENCE, 0
    stress = 0
    if language == IPA:
        symbol, stress = parse_ipa(text)
        if symbol in inventory.symbols:
            return symbol, stress
        raise VispeechError(f"IPA phone {label!r} ({symbol}) has no articulatory features in vispeech")
    if language == "en":
        symbol = text.upper()
        if symbol[-1:] in ("0", "1", "2"):
            symbol, stress = symbol[:-1], int(symbol[-1])
    else:
        symbol = text
        if symbol[:1] in _SWEDISH_STRESS_MARKS:
            symbol, stress = symbol[1:], _SWEDISH_STRESS_MARKS[symbol[0]]
    if symbol in inventory.symbols and not is_silence(symbol):
        return symbol, stress
    raise VispeechError(f"unknown phone symbol {label!r} for language {language}")


def guess_language(labels: Iterable[str], starts: Sequence[float] | None = None) -> str:
    """``"en"`` if every non-silence label is ARPAbet, else ``"sv"`` if all are Swedish, else
    ``"ipa"`` if all are IPA segments.

    Labels with no phone at all (only silences) count as English; IPA labels that are also
    Swedish symbols (``m a t``) read as Swedish. Raises :class:`VispeechError` naming the first
    label that is none of these, and its position (and start time in seconds, given ``starts``).
    """
    labels = list(labels)

    def where(position: int) -> str:
        return f"phone {position}" + (f" at {starts[position]:.3f} s" if starts is not None else "")

    sets = {"en": "ARPAbet", "sv": "Swedish", IPA: "IPA"}
    for language in sets:
        if all(_parses(label, language) for label in labels):
            return language
    parses = {language: [_parses(label, language) for label in labels] for language in sets}
    for position, label in enumerate(labels):
        if not any(parses[language][position] for language in sets):
            raise VispeechError(f"unknown phone symbol {label!r} ({where(position)}): neither ARPAbet, Swedish nor IPA")
    best = max(sets, key=lambda language: sum(parses[language]))
    position = parses[best].index(False)
    raise VispeechError(
        f"unknown phone symbol {labels[position]!r} ({where(position)}): the other phones are {sets[best]}"
    )


def is_vowel(symbol: str, language: str) -> bool:
    """True if ``symbol`` (an inventory symbol, no stress mark) is a vowel of ``language``."""
    return symbol in get_inventory(language).vowels


def _parses(label: str, language: str) -> bool:
    try:
        parse_symbol(label, language)
    except VispeechError:
        return False
    return True
