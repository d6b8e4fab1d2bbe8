"""How glad or sorry a text sounds, in English and Swedish, by rules on its words: what the face's
``expression`` layer (:mod:`vispeech.motion.life`) smiles or frowns by.

:func:`sentiment` scores a text from -1 (sad, sorry, bad news) to 1 (glad, thankful, good
news) with a small lexicon of the words chat replies carry (:data:`LEXICON`: each word
``+1`` or ``-1``, ``±2`` for strong ones; a word matches a stem of four letters or more by its
start, so "thanks", "thanked" and "thankful" all match "thank", and a shorter one whole), read
word by word:

- a negation (*not*, *no*, *never*, *n't*; *inte*, *ej*, *aldrig*, *ingen*) turns the next
  three words' valence to −0.6 of it ("not bad" is mildly good, "not happy" rather sad);
- an intensifier (*very*, *really*, *so*; *mycket*, *väldigt*, *jätte*) before a word counts it
  1.5 times; an exclamation mark adds a fifth to its sentence's words;
- the sum over the words, over the square root of the number of words plus 2 (a long reply
  needs more glad words than a short one to sound as glad), squashed by ``tanh``.

Any other language scores 0 (neutral): the rules know only these two. Nothing is downloaded:
the lexicon is here.
"""

from __future__ import annotations

import math
import re

_EN_POSITIVE = (
    "good great glad happy happi love lovely like enjoy fun funny nice wonderful excellent awesome amazing "
    "fantastic perfect beautiful brilliant thank welcome congrat pleased pleasure pleasant delight hope smil "
    "laugh cool best better "
    "kind friend sure yes yay hooray success win won well fine super exciting excited glorious cheer sweet "
    "fabulous marvel terrific splendid proud relax relief comfort calm brave bright joy :) :-)"
)
_EN_NEGATIVE = (
    "bad sad sorry unfortunat terribl awful hate problem wrong error fail difficult hard pain hurt angry anger "
    "afraid fear scare worr sick ill tired lost lose loss die died dead death cry cries crying unhappy "
    "disappoint annoy bored boring "
    "horribl worst worse poor upset trouble danger miss lonely alone broke damag fault guilt regret grief "
    "mourn stress nervous anxious unable sadly sadness badly :( :-("
)
_SV_POSITIVE = (
    "bra jättebra toppen glad glat lycklig älsk gilla tack välkommen grattis perfekt utmärkt fin fint vacker "
    "härlig underbar fantastisk rolig kul trevlig skön hoppas le skratt bäst bättre snäll vän absolut ja "
    "lyckad lyckades vinna vann super spännande stolt lugn lättnad trygg mysig gärna härligt :) :-)"
)
_SV_NEGATIVE = (
    "dålig dåligt ledsen ledsna tyvärr hemsk fruktansvärd hat problem fel misslyck svår ont arg ilska rädd "
    "orolig oro sjuk trött förlor dog död gråt olycklig besvik irriter tråkig sämst sämre stackars synd "
    "jobbig fara saknar ensam trasig skada skuld ångra sorg stress nervös ängslig omöjlig :( :-("
)
_STRONG = frozenset("love wonderful excellent awesome amazing fantastic perfect brilliant hate terribl awful horribl "
                    "worst death died dead grief älsk underbar fantastisk perfekt utmärkt hemsk fruktansvärd "
                    "sämst död sorg".split())  # fmt: skip


def _lexicon(positive: str, negative: str) -> dict[str, float]:
    words = {w: 1.0 for w in positive.split()} | {w: -1.0 for w in negative.split()}
    return {w: v * (2.0 if w in _STRONG else 1.0) for w, v in words.items()}


LEXICON: dict[str, dict[str, float]] = {
    "en": _lexicon(_EN_POSITIVE, _EN_NEGATIVE),
    "sv": _lexicon(_SV_POSITIVE, _SV_NEGATIVE),
}
"""Per language, word stems and their valence."""
NEGATIONS = {"en": {"not", "no", "never", "n't", "neither", "nor"}, "sv": {"inte", "ej", "aldrig", "ingen", "icke"}}
INTENSIFIERS = {
    "en": {"very", "really", "so", "extremely", "truly", "absolutely", "too"},
    "sv": {"mycket", "väldigt", "jätte", "riktigt", "verkligen", "så", "otroligt"},
}
NEGATION_REACH, NEGATED, INTENSITY, EXCLAIMED = 3, -0.6, 1.5, 1.2
_WORD = re.compile(r":-?[()]|n't|[\w'-]+|[.?!]")


def _valence(word: str, lexicon: dict[str, float]) -> float:
    """The valence of ``word``: its own, else that of the longest stem of four letters or more it starts with."""
    for end in range(len(word), 3, -1):
        value = lexicon.get(word[:end])
        if value is not None:
            return value
    return lexicon.get(word, 0.0)


def sentiment(text: str, language: str) -> float:
    """How glad (up to 1) or sorry (down to -1) ``text`` in ``language`` sounds (see the module
    docstring); 0 for a language other than English and Swedish (``en``, ``en-gb``, ``sv``, ...)."""
    language = language.split("-")[0].lower()
    lexicon = LEXICON.get(language)
    if lexicon is None:
        return 0.0
    total, words, sentence = 0.0, 0, 0.0
    negated, boost = 0, 1.0
    for token in _WORD.findall(text.lower().replace("n't", " n't")):
        if token in ".?!":
            total += (EXCLAIMED - 1) * sentence if token == "!" else 0.0
            sentence, negated, boost = 0.0, 0, 1.0
            continue
        words += 1
        value = _valence(token, lexicon) * boost
        if negated:
            value *= NEGATED
            negated -= 1
        if token in NEGATIONS[language]:
            negated = NEGATION_REACH
        boost = INTENSITY if token in INTENSIFIERS[language] else 1.0
        sentence += value
        total += value
    return math.tanh(total / math.sqrt(words + 2)) if words else 0.0
