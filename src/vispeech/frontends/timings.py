"""Phones from the timings a voice service gives with its audio: words, characters or visemes
with times, as ElevenLabs, Azure and others send them.

**Words** (Azure's word boundaries, a transcript with word times): each word is spoken by
espeak-ng on its own (:func:`~vispeech.frontends.espeak.synthesize`, once per word and
language, then remembered) and its phones are laid over the word's given span, keeping espeak's
proportions between them: the alignment :func:`vispeech.frontends.dtw_align.dtw_align` would
find with the word boundaries pinned, without the audio. The time between words is silence.
A word without a letter or digit ("—", "...") is no word: its time is silence too.

**Characters** (ElevenLabs' alignment: ``characters`` with their start and end times): the
runs of characters between white space are words, from their first character's start to their
last one's end (:func:`characters_to_words`).

**Visemes** (Azure's viseme ids 0–21, Oculus/OVRLipSync's 15 names): each viseme reads as the
English (ARPAbet) phone it shows (:data:`VISEME_PHONES`), from its time to the next viseme's,
so the phone models animate it and post-processing's overlays close the lips on ``PP`` / 21
and bring the lower lip to the teeth on ``FF`` / 18.

Times are seconds from the start of the audio.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import SILENCE, parse_symbol

AZURE_VISEMES: tuple[str, ...] = (
    "sil",
    "AH1",
    "AA1",
    "AO1",
    "EH1",
    "ER1",
    "IY1",
    "UW1",
    "OW1",
    "AW1",
    "OY1",
    "AY1",
    "HH",
    "R",
    "L",
    "S",
    "SH",
    "DH",
    "F",
    "T",
    "K",
    "P",
)
"""The English phone each of Azure's viseme ids 0–21 shows (Azure's table: 0 silence, 1 æ ə ʌ,
2 ɑ, 3 ɔ, 4 ɛ ʊ, 5 ɝ, 6 j i ɪ, 7 w u, 8 o, 9 aʊ, 10 ɔɪ, 11 aɪ, 12 h, 13 ɹ, 14 l, 15 s z,
16 ʃ tʃ dʒ ʒ, 17 ð, 18 f v, 19 d t n θ, 20 k g ŋ, 21 p b m)."""

OCULUS_PHONES: dict[str, str] = {
    "sil": "sil",
    "PP": "P",
    "FF": "F",
    "TH": "TH",
    "DD": "D",
    "kk": "K",
    "CH": "CH",
    "SS": "S",
    "nn": "N",
    "RR": "R",
    "aa": "AA1",
    "E": "EH1",
    "ih": "IH1",
    "oh": "OW1",
    "ou": "UW1",
}
"""The English phone each of the 15 Oculus/OVRLipSync visemes shows."""

VISEME_PHONES: dict[int | str, str] = dict(enumerate(AZURE_VISEMES)) | OCULUS_PHONES
"""Azure's viseme ids and the Oculus viseme names, each with the English phone it shows."""

LAST_VISEME_SECONDS = 0.1
"""How long a stream's last viseme lasts when the audio ends before it would."""


def viseme_phone(viseme: int | str) -> tuple[str, int]:
    """The English phone (symbol, stress) a viseme shows: an Azure id (0–21) or an Oculus name
    (``PP``, ``aa``, ...; also ``viseme_PP`` and ``I`` / ``O`` / ``U``)."""
    key: int | str = viseme
    if isinstance(viseme, str):
        name = viseme.removeprefix("viseme_")
        key = {"I": "ih", "O": "oh", "U": "ou"}.get(name, name)
    if isinstance(key, bool) or key not in VISEME_PHONES:
        raise VispeechError(f"unknown viseme {viseme!r}: use an Azure viseme id 0-21 or an Oculus viseme name")
    return parse_symbol(VISEME_PHONES[key], "en")


def characters_to_words(characters: Sequence[str], starts: Sequence[float], ends: Sequence[float]) -> list[Word]:
    """The words of timed characters: each run of characters between white space, from its first
    character's start to its last one's end."""
    if not len(characters) == len(starts) == len(ends):
        raise VispeechError(
            f"characters and their times must be as many: {len(characters)} characters, "
            f"{len(starts)} starts, {len(ends)} ends"
        )
    words: list[Word] = []
    run: list[int] = []
    for i, char in enumerate([*characters, " "]):
        if char.strip():
            run.append(i)
        elif run:
            words.append(Word("".join(characters[k] for k in run), starts[run[0]], ends[run[-1]]))
            run = []
    return words


def is_word(text: str) -> bool:
    """Whether ``text`` has something to speak (a letter or a digit)."""
    return any(char.isalnum() for char in text)


def word_phones(text: str, language: str) -> tuple[Phone, ...]:
    """espeak-ng's phones of the word ``text`` spoken on its own in ``language``, their times as
    shares of the word's span (the first starts at 0, the last ends at 1), in the language's
    phone set (:func:`~vispeech.frontends.espeak.phone_set`); none for a word without a letter or digit."""
    return _word_phones(text.strip(), language) if is_word(text) else ()


@functools.lru_cache(maxsize=4096)
def _word_phones(text: str, language: str) -> tuple[Phone, ...]:
    from vispeech.frontends.espeak import synthesize

    phones = synthesize(text, language, reproducible=False).phones.phones
    spoken = [k for k, p in enumerate(phones) if not p.is_silence]
    if not spoken:
        return ()
    inner = phones[spoken[0] : spoken[-1] + 1]
    begin, span = inner[0].start, inner[-1].end - inner[0].start
    return tuple(Phone(p.symbol, (p.start - begin) / span, (p.end - begin) / span, None, p.stress) for p in inner)


def phones_over_words(words: Sequence[Word], language: str, begin: float = 0.0) -> list[Phone]:
    """The phones of ``words`` (in time order) laid over their spans (see the module docstring),
    silence between them and from ``begin`` to the first. A word starting before the one before
    it ends (or before ``begin``) starts there; one ending there is refused; a word without a letter
    or digit is passed over, whatever its times."""
    out: list[Phone] = []
    time = begin
    for word in words:
        pieces = word_phones(word.text, language)
        if not pieces:
            continue
        if word.end <= time + TIME_TOLERANCE:
            raise VispeechError(
                f"word {word.text!r} ends at {word.end:.3f} s, before the words before it end ({time:.3f} s)"
            )
        start = max(word.start, time)
        if start > time + TIME_TOLERANCE:
            out.append(Phone(SILENCE, time, start))
        span = word.end - start
        out += [Phone(p.symbol, start + p.start * span, start + p.end * span, None, p.stress) for p in pieces]
        time = word.end
    return out


def phones_over_visemes(visemes: Sequence[tuple[int | str, float]], end: float, begin: float = 0.0) -> list[Phone]:
    """The phones of timed visemes (``(viseme, time)`` in time order, none before ``begin``),
    each from its time to the next one's, the last to ``end``; silence from ``begin`` to the first."""
    out: list[Phone] = []
    time = begin
    for k, (viseme, start) in enumerate(visemes):
        if start < time - TIME_TOLERANCE:
            raise VispeechError(f"viseme {viseme!r} at {start:.3f} s comes before {time:.3f} s")
        stop = visemes[k + 1][1] if k + 1 < len(visemes) else end
        if start > time + TIME_TOLERANCE:
            out.append(Phone(SILENCE, time, start))
        if stop > max(start, time) + TIME_TOLERANCE:
            symbol, stress = viseme_phone(viseme)
            out.append(Phone(symbol, max(start, time), stop, None, stress))
            time = stop
    return out


def timed_word_phones(words: Sequence[Word], language: str, duration: float) -> PhoneSequence:
    """The phone sequence of timed ``words`` over ``[0, duration]`` (at least up to the last
    word's end): what a stream of these timings animates, offline."""
    from vispeech.frontends.espeak import phone_set

    phones = phones_over_words(words, language)
    end = phones[-1].end if phones else 0.0
    if duration > end + TIME_TOLERANCE or not phones:
        phones.append(Phone(SILENCE, end, max(duration, end + TIME_TOLERANCE)))
    return PhoneSequence(phones, phone_set(language)).validate()
