"""IPA phones: the phone set of every language without a curated inventory.

A phone in IPA is one *segment*: a base letter of the International Phonetic Alphabet (or an
affricate or double articulation written as two letters, ``ts`` ``tʃ`` ``kp``), or a
diphthong (two vowel letters, ``aɪ``), with three modifiers kept because the face shows them:
labialisation ``ʷ`` (rounded, protruded lips), rhoticity ``˞`` (``ɚ`` is ``ə˞``) and length
``ː``. Everything else a transcription may carry is read and dropped: stress marks (``ˈ``
primary, ``ˌ`` secondary: they become the phone's stress), tie bars, aspiration,
palatalisation, velarisation, nasalisation, voicing and syllabicity marks, tone letters and
marks, and the other diacritics of :data:`DROPPED`. :func:`parse_ipa` turns a label into a
segment; :func:`split_ipa` turns a string of several (an espeak-ng phoneme such as Danish
``ʔo``) into segments.

The articulatory features of a segment come from its base letters' rows in PanPhon's
feature table (24 SPE-style features, +1/0/-1), mapped onto
:data:`vispeech.phonetics.features.FEATURE_NAMES` by :func:`ipa_features`. The rows ship as
``data/panphon.tsv`` (PanPhon's ``ipa_all.csv`` rows for its base segments, with PanPhon's
credit and MIT licence; ``tests/panphon_table.py`` writes it from the ``panphon`` package and
the tests check it), so neither panphon nor the pandas it pulls is needed to run, and reading
it takes about a millisecond. Where PanPhon's binary features do not make a distinction the face
needs, the mapping names the letters: central vowels (PanPhon has no central value), the
labiodental nasal and approximant ``ɱ ʋ`` (PanPhon marks only labiodental fricatives, by
stridency), the glottals ``h ɦ ʔ`` (PanPhon's ``h`` has the features of a uvular) and ``ɧ``.
Uvulars map to ``velar`` and pharyngeals to ``glottal``, the nearest places the feature
set has; clicks and implosives are stops at their place.

Conventions follow the curated inventories (``data/features.tsv``): diphthongs carry their
onset quality, ``long`` and ``diphthong``, and half rounding when only the glide is rounded;
postalveolar sibilants (``ʃ ʒ tʃ dʒ``) have half-rounded, protruded lips; rounded
consonants (``w``, ``ʷ``) are fully rounded and protruded.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass
from functools import cache
from importlib import resources

from vispeech.errors import VispeechError

STRESS_MARKS = {"ˈ": 1, "ˌ": 2}
"""Stress marks before or inside a segment, and the stress they give."""

LENGTH, LABIALISED, RHOTIC = "ː", "ʷ", "˞"
"""The modifiers a segment keeps."""

_TIE_BARS = "\u0361\u035c"
_TONE_LETTERS = "˥˦˧˨˩꜈꜉꜊꜋꜌"
DROPPED = frozenset(
    "ʰʱʲˠˤˀʼⁿˡˑᵝ"  # aspiration, palatalised, velarised, pharyngealised, glottalised, ejective,
    # nasal and lateral release, half-long, compressed
    "\u0303\u0325\u030a\u032c\u0329\u030d\u032f\u0311\u0306\u031e\u031d\u0318\u0319\u031f\u0320"
    "\u0308\u033d\u031a\u0339\u031c\u0324\u0330\u033c\u033a\u033b\u0334"
    "\u032a"  # dental, where the letter has no dental base (t̪ d̪ n̪ s̪ ... are bases)
    "\u0301\u0300\u0302\u030c\u0304\u030b\u030f\u1dc4\u1dc5\u1dc8" + _TONE_LETTERS  # combining tone marks
)
"""Diacritics and modifier letters read and dropped (see the module docstring)."""

_ALIASES = {
    "g": "ɡ",
    ":": LENGTH,
    "ɚ": "ə" + RHOTIC,
    "ɝ": "ɜ" + RHOTIC,
    "ʦ": "ts",
    "ʧ": "tʃ",
    "ʤ": "dʒ",
    "ʣ": "dz",
    "ʨ": "tɕ",
    "ʥ": "dʑ",
    "ɩ": "ɪ",
    "ɷ": "ʊ",
    "ε": "ɛ",
    "φ": "ɸ",
    "Φ": "ɸ",
}
"""Letters read as others: ASCII g and colon, r-coloured vowels, ligatures, obsolete letters,
Greek letters for their IPA look-alikes."""

_CENTRAL = frozenset("ɨʉɘɵəɜɞɐa")
"""Vowels PanPhon files as front or back that the IPA chart puts central (``a``: as most
transcriptions, espeak-ng's included, use it)."""
_LABIODENTAL = frozenset("ɱʋ")
_GLIDES = {"j": "i", "w": "u", "ɥ": "y", "ɰ": "ɯ"}
"""Glides that end a diphthong, as the vowels they glide to."""
_GLOTTAL = {"h": "fricative", "ɦ": "fricative", "ʔ": "stop"}
_SJ = {"velar": 1.0, "postalveolar": 1.0, "fricative": 1.0, "rounded": 1.0, "protruded": 1.0, "voiced": 0.0}
"""ɧ, the Swedish sj-sound: a simultaneous postalveolar and velar fricative, rounded lips
(PanPhon gives it the features of a palatal); as the Swedish inventory's ``S``."""
_POSTALVEOLAR_SIBILANT_ROUNDING = (0.5, 1.0)


@dataclass(frozen=True)
class _Segment:
    """A parsed segment: its base letters (one, or two for affricates and diphthongs), modifiers, stress."""

    bases: tuple[str, ...]
    labialised: bool = False
    rhotic: bool = False
    long: bool = False
    stress: int = 0

    @property
    def symbol(self) -> str:
        return "".join(self.bases) + LABIALISED * self.labialised + RHOTIC * self.rhotic + LENGTH * self.long


@cache
def _panphon() -> tuple[tuple[str, ...], dict[str, dict[str, int]]]:
    """PanPhon's base segments (tone letters left out) and their feature rows, NFD-normalised."""
    text = resources.files("vispeech.phonetics").joinpath("data/panphon.tsv").read_text(encoding="utf-8")
    lines = [line.split("\t") for line in text.splitlines() if line and not line.startswith("#")]
    names = lines[0][1:]
    value = {"+": 1, "-": -1, "0": 0}
    rows = {fields[0]: {name: value[v] for name, v in zip(names, fields[1:], strict=True)} for fields in lines[1:]}
    return tuple(rows), rows


@cache
def _letters() -> dict[str, str]:
    """Every base as written in a phone symbol (tie bars removed) -> PanPhon's spelling."""
    return {_untied(b): b for b in _panphon()[0]}


def _untied(text: str) -> str:
    """``text`` without tie bars (``t͡ʃ`` -> ``tʃ``)."""
    return "".join(c for c in text if c not in _TIE_BARS)


@cache
def _longest_letter() -> int:
    return max(len(k) for k in _letters())


def _is_vowel_base(base: str) -> bool:
    row = _panphon()[1][_letters()[base]]
    return row["syl"] > 0 and row["cons"] < 0


def split_ipa(text: str) -> list[tuple[str, int]]:
    """The segments of an IPA string, each as ``(symbol, stress)``.

    Two vowels in a row make a diphthong (a third starts a new segment) and a stop followed by
    a fricative or a second stop makes an affricate or double articulation where PanPhon has
    one (``ts``, ``tʃ``, ``kp``); other letters are segments of their own. Stress goes to the
    first vowel after the mark. Raises :class:`VispeechError` naming the symbol and the
    character position for a letter that is not IPA.
    """
    return [(s.symbol, s.stress) for s in _segments(text)]


def parse_ipa(label: str) -> tuple[str, int]:
    """``(symbol, stress)`` of a label that holds one IPA segment (see :func:`split_ipa`)."""
    segments = _segments(label)
    if len(segments) != 1:
        what = "no segment" if not segments else f"{len(segments)} segments ({' '.join(s.symbol for s in segments)})"
        raise VispeechError(f"IPA phone {label!r} holds {what}, not one")
    return segments[0].symbol, segments[0].stress


def _segments(text: str) -> list[_Segment]:
    letters = _letters()
    longest = _longest_letter()
    normal = unicodedata.normalize("NFD", text.strip())
    chars = "".join(_ALIASES.get(c, c) for c in normal)
    units: list[dict] = []  # one per base letter: bases, modifiers, stress
    stress, i = 0, 0
    while i < len(chars):
        c = chars[i]
        if c in STRESS_MARKS:
            stress = max(stress, STRESS_MARKS[c]) if stress else STRESS_MARKS[c]
            i += 1
            continue
        if c in DROPPED or c in _TIE_BARS or c.isspace() or c == ".":  # "." is a syllable boundary
            i += 1
            continue
        if c in (LENGTH, LABIALISED, RHOTIC):
            if not units:
                raise VispeechError(f"IPA {text!r}: {c!r} at position {i} modifies no segment")
            units[-1][{LENGTH: "long", LABIALISED: "labialised", RHOTIC: "rhotic"}[c]] = True
            i += 1
            continue
        for size in range(min(longest, len(chars) - i), 0, -1):  # longest base first (t̪, d̪͡z̪ ...)
            candidate = _untied(chars[i : i + size])
            if candidate in letters:
                break
        else:
            raise VispeechError(f"IPA {text!r}: {c!r} at position {i} is not an IPA segment vispeech knows")
        units.append({"bases": (candidate,), "stress": 0})
        if stress and _is_vowel_base(candidate):
            units[-1]["stress"], stress = stress, 0
        i += size
    return _group(units, stress)


def _group(units: list[dict], trailing_stress: int) -> list[_Segment]:
    """Join a vowel (not long) and a different vowel or a glide after it into a diphthong (MFA's
    ``aj`` is ``ai``)."""
    segments: list[_Segment] = []
    k = 0
    while k < len(units):
        unit = units[k]
        following = units[k + 1] if k + 1 < len(units) else None
        glide = _GLIDES.get(following["bases"][0]) if following is not None else None
        if (
            following is not None
            and not unit.get("long")
            and _is_vowel_base(unit["bases"][0])
            and (glide or _is_vowel_base(following["bases"][0]))
            and unit["bases"] != following["bases"]
        ):
            segments.append(
                _Segment(
                    unit["bases"] + ((glide,) if glide else following["bases"]),
                    rhotic=bool(following.get("rhotic")),
                    stress=unit["stress"] or following["stress"],
                )
            )
            k += 2
            continue
        segments.append(
            _Segment(
                unit["bases"],
                bool(unit.get("labialised")),
                bool(unit.get("rhotic")),
                bool(unit.get("long")),
                unit["stress"],
            )
        )
        k += 1
    if trailing_stress and segments and not any(s.stress for s in segments):  # no vowel after the mark
        vowels = [n for n, s in enumerate(segments) if _is_vowel_base(s.bases[0])]
        if vowels:
            n = vowels[-1]
            segments[n] = _Segment(
                segments[n].bases, segments[n].labialised, segments[n].rhotic, segments[n].long, trailing_stress
            )
    return segments


@cache
def ipa_symbols() -> tuple[tuple[str, ...], frozenset[str]]:
    """``(symbols, vowels)``: every IPA phone symbol vispeech has a row for.

    Consonants plain and labialised, each short and long; vowels short, long and (``ə ɜ``)
    r-coloured; every diphthong of two different vowels.
    """
    bases = list(_letters())
    vowels = [b for b in bases if _is_vowel_base(b)]
    consonants = [b for b in bases if not _is_vowel_base(b)]
    symbols = [c + w + n for c in consonants for w in ("", LABIALISED) for n in ("", LENGTH)]
    vowel_symbols = [v + n for v in vowels for n in ("", LENGTH)] + ["ə" + RHOTIC, "ɜ" + RHOTIC]
    vowel_symbols += [a + b for a in vowels for b in vowels if a != b]
    return tuple(symbols + vowel_symbols), frozenset(vowel_symbols)


def ipa_features(symbol: str) -> dict[str, float]:
    """The non-zero articulatory features of one IPA phone symbol (stress left out).

    Keys are names of :data:`vispeech.phonetics.features.FEATURE_NAMES`; raises
    :class:`VispeechError` for a symbol that is not one segment.
    """
    segments = _segments(symbol)
    if len(segments) != 1 or segments[0].stress:
        raise VispeechError(f"{symbol!r} is not an IPA phone symbol")
    segment = segments[0]
    rows = _panphon()[1]
    letters = _letters()
    onset = segment.bases[0]
    row = rows[letters[onset]]
    if _is_vowel_base(onset):
        out = _vowel(onset, row)
        if len(segment.bases) == 2:
            glide = rows[letters[segment.bases[1]]]
            out.update(diphthong=1.0, long=1.0)
            if not out.get("rounded") and glide["round"] > 0:
                out["rounded"] = 0.5
    else:
        out = _consonant(onset, row)
    if segment.labialised:
        out.update(rounded=1.0, protruded=1.0)
    if segment.rhotic:
        out.update(
            retroflex=1.0, rounded=max(out.get("rounded", 0.0), 0.5), protruded=max(out.get("protruded", 0.0), 0.5)
        )
    if segment.long:
        out["long"] = 1.0
    return {name: value for name, value in out.items() if value}


def _vowel(letter: str, row: dict[str, int]) -> dict[str, float]:
    """Height (``open`` 0, 0.5, 1), backness (``front`` 1, 0.5, 0), rounding of a vowel letter."""
    central = letter in _CENTRAL
    mid = row["hi"] <= 0 and row["lo"] <= 0
    out = {
        "vowel": 1.0,
        "voiced": 1.0,
        "open": 0.0 if row["hi"] > 0 else (1.0 if row["lo"] > 0 else 0.5),
        "front": 0.5 if central else (0.0 if row["back"] > 0 else 1.0),
        "open_mid": float(mid and row["tense"] < 0 and letter != "ə"),
    }
    if row["round"] > 0:
        out["rounded"] = 1.0
        close = row["hi"] > 0 or (row["back"] > 0 and mid and row["tense"] > 0)
        out["protruded"] = 0.0 if central else (1.0 if close else 0.5)
    return out


def _consonant(letter: str, row: dict[str, int]) -> dict[str, float]:
    """Place, manner, voicing and lip rounding of a consonant (or affricate) letter."""
    f = {name: value > 0 for name, value in row.items()}
    out: dict[str, float] = {"voiced": float(f["voi"])}
    affricate = f["delrel"] and not f["cont"]
    if letter == "ɧ":
        return dict(_SJ)
    if letter[0] in _GLOTTAL:
        out["glottal"] = 1.0
        out[_GLOTTAL[letter[0]]] = 1.0
        return out
    labial = f["lab"] and f["cons"] or letter[0] in _LABIODENTAL
    if labial and ((f["strid"] and f["cont"]) or letter[0] in _LABIODENTAL):
        out["labiodental"] = 1.0
    elif labial:
        out["bilabial"] = 1.0  # also the stop of an affricate (pf) and a bilabial click
    if f["cor"]:
        if f["ant"]:
            out["dental" if row["distr"] > 0 else "alveolar"] = 1.0
        elif row["distr"] > 0 and f["hi"]:  # ɕ ʑ (sibilant), ʎ
            out["palatal"] = 1.0
            if f["strid"]:
                out["postalveolar"] = 1.0
        elif row["distr"] > 0:
            out["postalveolar"] = 1.0
            if f["strid"]:
                out["rounded"], out["protruded"] = _POSTALVEOLAR_SIBILANT_ROUNDING
        else:
            out["retroflex"] = 1.0
    elif f["back"] and f["lo"]:
        out["glottal"] = 1.0  # pharyngeal
    elif f["back"]:
        out["velar"] = 1.0  # velar and uvular (w, k͡p with their lips)
    elif f["hi"] and not labial:
        out["palatal"] = 1.0
    if f["nas"]:
        out["nasal"] = 1.0
    elif not f["cont"]:
        out["stop"] = 1.0
        if affricate:
            out["fricative"] = 1.0
    elif f["son"]:
        out["approximant"] = 1.0
    else:
        out["fricative"] = 1.0
    if f["lat"]:
        out["lateral"] = 1.0
    if f["round"] and f["lab"]:
        out["rounded"], out["protruded"] = 1.0, 1.0
    elif f["round"]:
        out["rounded"], out["protruded"] = 0.5, 0.5  # ɹ: PanPhon's rounding without a labial gesture
    return out
