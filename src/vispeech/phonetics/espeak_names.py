"""espeak-ng phoneme names to inventory symbols.

For Swedish and English, espeak-ng reports phonemes by their ASCII mnemonics (``'E``,
``u-``, ``aI@``), prefixed with a stress mark, and :func:`espeak_to_symbols` maps them onto
the curated inventories. The tables below cover every sounding phoneme of espeak-ng 1.52's
``sv`` table and of ``en-us`` (with ``en``), each on top of the shared ``base1`` consonants.
Every other language is read with espeak-ng's IPA option (:func:`espeak_ipa_to_symbols`):
a phoneme's IPA string (cut at 8 bytes, which no phoneme seen so far reaches), or, for the
few phonemes espeak-ng gives no IPA, its mnemonic with the ASCII letters that have an IPA
reading converted (``tS`` ``n^`` ``s.``).

Swedish voice output can switch to English pronunciation for loanwords (``(en)`` ...
``(sv)`` events); such names are read with the English table and carried over to the
nearest Swedish phones. An r-coloured English vowel becomes two ARPAbet phones (``A@`` ->
``AA R``, ``aI@`` -> ``AY ER``), as CMUdict writes them.
"""

from __future__ import annotations

from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import SILENCE, get_inventory, is_vowel
from vispeech.phonetics.ipa import DROPPED, LABIALISED, LENGTH, RHOTIC, STRESS_MARKS, split_ipa

# Consonants of espeak's base1 table, shared by every voice.
_BASE1_SV = {
    "p": "p",
    "b": "b",
    "t": "t",
    "d": "d",
    "k": "k",
    "g": "g",
    "t[": "t",
    "d[": "d",
    "?": "t",
    "c": "k",
    "q": "k",
    "J": "j",
    "m": "m",
    "n": "n",
    "N": "N",
    "n^": "n",
    "n.": "rn",
    "m-": "m",
    "n-": "n",
    "N-": "N",
    "l-": "l",
    "r-": "r",
    "f": "f",
    "v": "v",
    "v#": "v",
    "B": "b",
    "T": "t",
    "D": "d",
    "s": "s",
    "z": "s",
    "S": "S",
    "Z": "S",
    "s.": "rs",
    "z.": "rs",
    "s;": "C",
    "z;": "C",
    "S;": "C",
    "Z;": "C",
    "C": "C",
    "x": "S",
    "X": "h",
    "#X1": "h",
    "h": "h",
    "Q": "g",
    "Q^": "g",
    'Q"': "r",
    "tS": "C",
    "tS;": "C",
    "dZ": "j",
    "dZ;": "j",
    "J^": "j",
    "j": "j",
    "w": "v",
    "l": "l",
    "l/": "l",
    "l/2": "l",
    "l/3": "l",
    "L": "l",
    "L/": "l",
    "l^": "l",
    "l#": "l",
    "l.": "rl",
    "r": "r",
    "r/": "r",
    "R": "r",
    "R2": "r",
    "R3": "r",
    'r"': "r",
    "r.": "r",
    "*": "r",
    "**": "r",
}
_BASE1_EN = {
    "p": "P",
    "b": "B",
    "t": "T",
    "d": "D",
    "k": "K",
    "g": "G",
    "t[": "T",
    "d[": "D",
    "?": "T",
    "c": "K",
    "q": "K",
    "J": "JH",
    "m": "M",
    "n": "N",
    "N": "NG",
    "n^": "N",
    "n.": "N",
    "m-": "M",
    "n-": "N",
    "N-": "NG",
    "l-": "L",
    "r-": "ER",
    "f": "F",
    "v": "V",
    "v#": "V",
    "B": "B",
    "T": "TH",
    "D": "DH",
    "s": "S",
    "z": "Z",
    "S": "SH",
    "Z": "ZH",
    "s.": "SH",
    "z.": "ZH",
    "s;": "SH",
    "z;": "ZH",
    "S;": "SH",
    "Z;": "ZH",
    "C": "HH",
    "x": "HH",
    "X": "HH",
    "#X1": "HH",
    "h": "HH",
    "Q": "G",
    "Q^": "G",
    'Q"': "R",
    "tS": "CH",
    "tS;": "CH",
    "dZ": "JH",
    "dZ;": "JH",
    "J^": "Y",
    "j": "Y",
    "w": "W",
    "l": "L",
    "l/": "L",
    "l/2": "L",
    "l/3": "L",
    "L": "L",
    "L/": "L",
    "l^": "L",
    "l#": "L",
    "l.": "L",
    "r": "R",
    "r/": "R",
    "R": "R",
    "R2": "R",
    "R3": "R",
    'r"': "R",
    "r.": "R",
    "*": "D",
    "**": "D",
}

_SV = {
    **_BASE1_SV,
    # vowels of espeak's sv table (and base1's generic ones)
    "i:": "i:",
    "I": "I",
    "i": "I",
    "e:": "e:",
    "e": "e",
    "E": "E",
    "E:": "E:",
    "E3": "{",
    "&": "{",
    "E-": "@",
    "@": "@",
    "@-": "@",
    "y:": "y:",
    "y": "Y",
    "u-": "}:",
    "8": "u0",
    "Y:": "2:",
    "W": "9",
    "A:": "A:",
    "a": "a",
    "O": "O",
    "o:": "o:",
    "o": "O",
    "U": "U",
    "u:": "u:",
    "u": "U",
    "sx": "S",  # the sj-sound
}
_EN = {
    **_BASE1_EN,
    # vowels of espeak's en and en-us tables
    "@": "AH",
    "@-": "AH",
    "@#": "AH",
    "@2": "AH",
    "@5": "UH",
    "@L": "AH L",
    "a#": "AH",
    "a#2": "AH",
    "V": "AH",
    "02": "AH",
    "VR": "AH R",
    "3": "ER",
    "3:": "ER",
    "a": "AE",
    "aa": "AE",
    "a2": "AE",
    "A:": "AA",
    "A#": "AA",
    "A~": "AA",
    "0": "AA",
    "0#": "AA",
    "A@": "AA R",
    "E": "EH",
    "E#": "EH",
    "E2": "EH",
    "e#": "EH",
    "e@": "EH R",
    "e": "EY",
    "e:": "EY",
    "eI": "EY",
    "i": "IY",
    "i:": "IY",
    "i@": "IY AH",
    "i@3": "IH R",
    "I": "IH",
    "I#": "IH",
    "I2": "IH",
    "I2#": "IH",
    "IR": "IH R",
    "O": "AO",
    "O:": "AO",
    "O2": "AO",
    "O~": "AO",
    "O@": "AO R",
    "o@": "AO R",
    "o": "OW",
    "o:": "OW",
    "oU": "OW",
    "oU#": "OW",
    "OI": "OY",
    "U": "UH",
    "U@": "UH R",
    "u": "UW",
    "u:": "UW",
    "aI": "AY",
    "aI@": "AY ER",
    "aI3": "AY ER",
    "aU": "AW",
    "aU@": "AW ER",
    "t#": "T",
    "t2": "T",
    "d#": "D",
    "z#": "Z",
    "z/2": "Z",
    "w#": "W",
}
# English phones in Swedish speech (loanwords spoken with the English table)
_ARPABET_TO_SV = {
    "AA": "A:",
    "AE": "{",
    "AH": "@",
    "AO": "O",
    "AW": "a U",
    "AY": "a j",
    "EH": "E",
    "ER": "9",
    "EY": "E j",
    "IH": "I",
    "IY": "i:",
    "OW": "O U",
    "OY": "O j",
    "UH": "U",
    "UW": "u:",
    "B": "b",
    "CH": "C",
    "D": "d",
    "DH": "d",
    "F": "f",
    "G": "g",
    "HH": "h",
    "JH": "j",
    "K": "k",
    "L": "l",
    "M": "m",
    "N": "n",
    "NG": "N",
    "P": "p",
    "R": "r",
    "S": "s",
    "SH": "S",
    "T": "t",
    "TH": "t",
    "V": "v",
    "W": "v",
    "Y": "j",
    "Z": "s",
    "ZH": "S",
}
_TABLES = {"sv": _SV, "en": _EN}

PAUSE_NAMES = frozenset({"", "_", "_:", "_!", "_|", "_::", "_;_", "||", "_^_", "_X1"})
"""espeak pause phonemes (the IPA option reports them with an empty name)."""


def espeak_to_symbols(name: str, language: str, table: str | None = None) -> tuple[tuple[str, int], ...]:
    """Inventory ``(symbol, stress)`` pairs for one espeak phoneme name.

    ``name`` is an ASCII phoneme mnemonic as espeak reports it, with an optional leading
    stress mark (``'`` primary: stress 1; ``,`` secondary: stress 2 in English, 0 in Swedish,
    whose stresses 1 and 2 are the word accents). ``table`` is the espeak phoneme table in
    effect (``"en"`` inside an English loanword of Swedish speech; default: ``language``'s).
    Pauses give ``(("sil", 0),)``; most phonemes give one pair, r-coloured English vowels
    two. Stress goes to the first vowel only.
    """
    get_inventory(language)
    bare = name.lstrip("',%=")
    if bare in PAUSE_NAMES:
        return ((SILENCE, 0),)
    marks = name[: len(name) - len(bare)]
    stress = 1 if "'" in marks else (2 if "," in marks and language == "en" else 0)
    source = "en" if table == "en" else language
    try:
        symbols = _TABLES[source][bare].split()
    except KeyError:
        raise VispeechError(f"espeak phoneme {name!r} has no {language} symbol") from None
    if source != language:
        symbols = [s for arpabet in symbols for s in _ARPABET_TO_SV[arpabet].split()]
    pairs = []
    for symbol in symbols:
        stressed = stress if is_vowel(symbol, language) else 0
        pairs.append((symbol, stressed))
        stress = 0 if stressed else stress
    return tuple(pairs)


# espeak-ng mnemonics left in IPA output where a phoneme defines no IPA: the letters they use.
_MNEMONIC_LETTERS = {
    "tS": "tʃ",
    "dZ": "dʒ",
    "ts": "ts",
    "dz": "dz",
    "S": "ʃ",
    "Z": "ʒ",
    "T": "θ",
    "D": "ð",
    "N": "ŋ",
    "C": "ç",
    "J": "ɲ",
    "R": "ʁ",
    "Q": "ɣ",
    "X": "χ",
    "B": "β",
    "G": "ɣ",
    "L": "ʎ",
    "A": "ɑ",
    "E": "ɛ",
    "I": "ɪ",
    "O": "ɔ",
    "U": "ʊ",
    "V": "ʌ",
    "Y": "ʏ",
    "W": "œ",
    "@": "ə",
    "3": "ɜ",
    "0": "ɒ",
    "8": "ɵ",
    "&": "æ",
    "?": "ʔ",
}
_MNEMONIC_MARKS = {
    "^": {"n": "ɲ", "l": "ʎ"},
    ".": {"s": "ʂ", "z": "ʐ", "t": "ʈ", "d": "ɖ", "n": "ɳ", "l": "ɭ", "r": "ɻ"},
}


def espeak_ipa_to_symbols(name: str) -> tuple[tuple[str, int], ...]:
    """IPA ``(symbol, stress)`` pairs for one phoneme as espeak-ng's IPA option reports it.

    Pauses (empty names) give ``(("sil", 0),)``; most phonemes give one pair, a phoneme that
    holds several segments (Danish ``ʔo``) one pair each, and one of modifiers only (a length
    mark of its own) none: it belongs to the phone before. Raises :class:`VispeechError` for
    a name that is not IPA, even read as a mnemonic.
    """
    bare = name.strip()
    if bare in PAUSE_NAMES:
        return ((SILENCE, 0),)
    if all(c in DROPPED or c in STRESS_MARKS or c in (LENGTH, LABIALISED, RHOTIC) or c.isdigit() for c in bare):
        return ()  # modifiers (or a bare variant digit) of the phone before
    mnemonic = any(c.isascii() and (c.isupper() or c in "#-.^[;:0123456789@&?`'\"") for c in bare)
    pairs = tuple(split_ipa(_from_mnemonic(bare) if mnemonic else bare))
    if not pairs:
        raise VispeechError(f"espeak phoneme {name!r} has no IPA segment")
    return pairs


def _from_mnemonic(name: str) -> str:
    """An espeak-ng mnemonic (after any IPA stress mark) in IPA letters: ``tS`` -> ``tʃ``, ``s.``
    -> ``ʂ``, ``t[`` -> ``t̪``; variant marks (``#``, ``-``, `````, digits after the first letter) dropped."""
    stress = "".join(c for c in name[:1] if c in "ˈˌ")
    text = name[len(stress) :]
    head = text[:2] if text[:2] in _MNEMONIC_LETTERS else text[:1]
    rest = text[len(head) :]
    letters = _MNEMONIC_LETTERS.get(head, head)
    for mark, table in _MNEMONIC_MARKS.items():
        if rest.startswith(mark) and letters in table:
            letters, rest = table[letters], rest[1:]
    if rest.startswith("["):
        letters, rest = letters + "\u032a", rest[1:]
    rest = "".join(c for c in rest if c not in "#-0123456789;`'\"")
    return stress + letters + rest
