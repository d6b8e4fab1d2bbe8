"""Text to speech with time-aligned phones, through libespeak-ng.

The library comes from the ``espeakng-loader`` wheel and is driven through ctypes in
synchronous mode with phoneme events. Every phone's onset is the sample espeak reports for
its phoneme event; a phone lasts until the next event (the last one to the end of the audio).
Every language espeak-ng ships a dictionary for is spoken (:func:`languages`), with any voice
(:func:`voices`). Swedish (``sv``) and English (``en``, voice file ``en-us``) phonemes are read
by their ASCII mnemonics into the curated inventories; every other language's by their IPA into
IPA phones (:func:`phone_set`), both by :mod:`vispeech.phonetics.espeak_names`. Pauses, and any
audio before the first phoneme, are ``sil``. In Swedish, ``r`` followed by ``t d n l s`` in the
same word merges into the retroflex (``rt rd rn rl rs``), as the MFA-style Swedish inventory
writes it. A phoneme with no IPA reading (none in espeak-ng 1.52's voices as far as tested) is
joined to the phone before it, with a :class:`PhoneWarning`.

Words are the blank-separated tokens of the text (``"$1,000,000"`` is one word however
many espeak reads out), stripped of surrounding punctuation, each from its first phone to
its last. espeak sometimes runs a short word into the one before ("for the"); the phones of
both then belong to the first.

espeak-ng runs in worker processes (:func:`vispeech.frontends.isolation.run_isolated`): a text
it crashes or hangs on is a :class:`~vispeech.errors.NativeFailure`, and the caller goes on.
In a worker it is global state: one module-level lock serialises every call. Its wave generator
also keeps state from one utterance to the next (the phase of its pitch flutter, its echo
buffer, its gain control are C statics), so within one process the same text would come out
a few samples longer or shorter each time, its phone onsets moving by up to a few ms and
jawOpen by up to 0.02. A call is therefore *reproducible* by default: it loads the library
afresh and unloads it after (about 7 ms more than reusing it, most of it reading the voice):
the same text, voice and rate give the same samples and phones in any process and any order
(what a batch writes equals what ``vispeech say`` writes, byte for byte). Live streams, where
latency counts and nothing is compared, pass ``reproducible=False`` and keep one library
loaded between calls (in each worker).
"""

from __future__ import annotations

import _ctypes
import bisect
import ctypes
import math
import re
import threading
import warnings
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.frontends.isolation import run_isolated
from vispeech.phonetics.espeak_names import espeak_ipa_to_symbols, espeak_to_symbols
from vispeech.phonetics.inventory import IPA, SILENCE, is_silence

CURATED = {"sv": "sv", "en": "en-us"}
"""The languages read into a curated inventory, and the espeak-ng voice each is spoken with."""

DEFAULT_WPM = 175
"""espeak-ng's default speaking rate in words per minute (``rate=1.0``)."""

MIN_RATE, MAX_RATE = 0.5, 2.5
"""Allowed speaking-rate factors (espeak-ng accepts 80 to 450 words per minute)."""

_PUNCTUATION = ".,;:!?()[]{}<>\"'«»“”„‘’…¡¿-–—"  # stripped from the ends of a word's text
_RETROFLEX = {"t": "rt", "d": "rd", "n": "rn", "l": "rl", "s": "rs"}

# espeak_lib.h constants
_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INITIALIZE_PHONEME_EVENTS = 0x1
_INITIALIZE_PHONEME_IPA = 0x2
_CHARS_UTF8 = 1
_RATE = 1
_EVENT_LIST_TERMINATED, _EVENT_WORD, _EVENT_PHONEME = 0, 1, 7


class PhoneWarning(UserWarning):
    """espeak-ng spoke a phoneme that has no phone in vispeech (it joins the phone before it)."""


@dataclass(frozen=True)
class Language:
    """A language espeak-ng speaks (espeak-ng calls it a voice): its code, its name and phone
    set, the voice file that speaks it, and the other codes that select it (``fr`` for
    ``fr-fr``, ``zh`` for ``cmn``)."""

    code: str
    name: str
    identifier: str
    phones: str
    aliases: tuple[str, ...] = ()

    @property
    def selector(self) -> str:
        """What selects this language's voice file in espeak-ng (``espeak_SetVoiceByName``)."""
        return CURATED.get(self.code, self.identifier)


@dataclass
class Speech:
    """Synthesised audio (float32 mono in [-1, 1]) with its time-aligned phones."""

    audio: np.ndarray
    sample_rate: int
    phones: PhoneSequence

    @property
    def duration(self) -> float:
        """Length of the audio in seconds."""
        return len(self.audio) / self.sample_rate


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_int),
        ("unique_identifier", ctypes.c_uint),
        ("text_position", ctypes.c_int),
        ("length", ctypes.c_int),
        ("audio_position", ctypes.c_int),
        ("sample", ctypes.c_int),
        ("user_data", ctypes.c_void_p),
        ("id", _EventId),
    ]


_Callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))


class _VoiceEntry(ctypes.Structure):
    _fields_ = [
        ("name", ctypes.c_char_p),
        ("languages", ctypes.c_void_p),
        ("identifier", ctypes.c_char_p),
        ("gender", ctypes.c_ubyte),
        ("age", ctypes.c_ubyte),
        ("variant", ctypes.c_ubyte),
        ("xx1", ctypes.c_ubyte),
        ("score", ctypes.c_int),
        ("spare", ctypes.c_void_p),
    ]


class _Engine:
    """The loaded library, its sample rate, and what the callback collects for one call.

    ``ipa``: phoneme events carry IPA names (else ASCII mnemonics), fixed when it starts.
    """

    def __init__(self, ipa: bool = False) -> None:
        import espeakng_loader

        self.ipa = ipa
        self.lib = ctypes.CDLL(espeakng_loader.get_library_path())
        self.lib.espeak_Initialize.restype = ctypes.c_int
        self.lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
        self.lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
        self.lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
        self.lib.espeak_Synth.argtypes = [
            ctypes.c_void_p,
            ctypes.c_size_t,
            ctypes.c_uint,
            ctypes.c_int,
            ctypes.c_uint,
            ctypes.c_uint,
            ctypes.c_void_p,
            ctypes.c_void_p,
        ]
        data_parent = str(Path(espeakng_loader.get_data_path()).parent).encode()
        options = _INITIALIZE_PHONEME_EVENTS | (_INITIALIZE_PHONEME_IPA if ipa else 0)
        rate = self.lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, data_parent, options)
        if rate <= 0:
            raise RuntimeError("could not initialise espeak-ng")
        self.sample_rate = rate
        self.chunks: list[np.ndarray] = []
        self.events: list[tuple] = []
        self.callback = _Callback(self._collect)  # kept alive as long as the engine
        self.lib.espeak_SetSynthCallback(self.callback)

    def _collect(self, wav, n_samples, events) -> int:
        if wav and n_samples > 0:
            self.chunks.append(np.ctypeslib.as_array(wav, shape=(n_samples,)).copy())
        i = 0
        while events and events[i].type != _EVENT_LIST_TERMINATED:
            event = events[i]
            if event.type == _EVENT_PHONEME:  # an IPA name cut at 8 bytes may end in half a character
                name = (
                    event.id.string.decode("utf-8", "ignore")
                    if self.ipa
                    else event.id.string.decode("ascii", "replace")
                )
                self.events.append(("phoneme", event.sample, name))
            elif event.type == _EVENT_WORD:
                self.events.append(("word", event.sample, event.text_position, event.length))
            i += 1
        return 0

    def synthesize(self, text: str, voice: str, wpm: int) -> tuple[np.ndarray, list[tuple]]:
        self.chunks, self.events = [], []
        if self.lib.espeak_SetVoiceByName(voice.encode()) != 0:
            raise RuntimeError(f"espeak-ng has no voice {voice!r}")
        self.lib.espeak_SetParameter(_RATE, wpm, 0)
        data = text.encode("utf-8") + b"\0"
        if self.lib.espeak_Synth(data, len(data), 0, 0, 0, _CHARS_UTF8, None, None) != 0:
            raise RuntimeError("espeak-ng failed to synthesise")
        self.lib.espeak_Synchronize()
        audio = np.concatenate(self.chunks) if self.chunks else np.zeros(0, np.int16)
        return audio, self.events

    def voices(self) -> list[tuple[list[tuple[int, str]], str, str]]:
        """``(languages, name, identifier)`` of every voice espeak-ng lists; ``languages``:
        ``(priority, code)`` pairs, the voice's own code first (a lower priority fits better)."""
        self.lib.espeak_ListVoices.restype = ctypes.POINTER(ctypes.POINTER(_VoiceEntry))
        self.lib.espeak_ListVoices.argtypes = [ctypes.c_void_p]
        entries = self.lib.espeak_ListVoices(None)
        found, i = [], 0
        while entries[i]:
            entry = entries[i].contents
            raw = ctypes.string_at(entry.languages, 256)  # (priority byte, code, NUL)..., then NUL
            languages, k = [], 0
            while k < len(raw) and raw[k] != 0:
                end = raw.index(b"\0", k + 1)
                languages.append((raw[k], raw[k + 1 : end].decode("ascii", "replace").lower()))
                k = end + 1
            found.append(
                (languages, entry.name.decode("utf-8", "replace"), entry.identifier.decode("utf-8", "replace"))
            )
            i += 1
        return found

    def close(self) -> None:
        """Terminate espeak-ng and unload the library, so that the next engine starts from its initial state."""
        self.lib.espeak_Terminate()
        _ctypes.dlclose(self.lib._handle)


_lock = threading.Lock()
_engine: _Engine | None = None  # kept loaded between calls that need not be reproducible


@cache
def languages() -> tuple[Language, ...]:
    """Every language espeak-ng can speak here, by code, sorted: the voices it lists whose
    pronunciation dictionary is installed (one voice per code), with ``en`` for ``en-us``."""
    import espeakng_loader

    with _lock:
        engine = _Engine()
        try:
            listed = engine.voices()
        finally:
            engine.close()
    data = Path(espeakng_loader.get_data_path())
    found: dict[str, Language] = {}
    ranked: dict[str, tuple[int, str]] = {}  # other code -> (priority, voice code)
    for languages, name, identifier in listed:
        code = languages[0][1]
        if code in found or not (data / f"{_dictionary(data, identifier, code)}_dict").is_file():
            continue
        found[code] = Language(code, name, identifier, IPA)
        for priority, other in languages[1:]:
            if other not in ranked or priority < ranked[other][0]:
                ranked[other] = (priority, code)
    found["sv"] = replace(found["sv"], phones="sv")
    found["en"] = replace(found.pop("en-us"), code="en", phones="en")  # the curated English
    aliases = {other: ("en" if code == "en-us" else code) for other, (_, code) in ranked.items()}
    aliases["en-us"] = "en"
    by_voice: dict[str, list[str]] = {}
    for other, code in sorted(aliases.items()):
        if other not in found and code in found:
            by_voice.setdefault(code, []).append(other)
    return tuple(
        sorted((replace(v, aliases=tuple(by_voice.get(v.code, ()))) for v in found.values()), key=lambda v: v.code)
    )


def _dictionary(data: Path, identifier: str, code: str) -> str:
    """The pronunciation dictionary a voice reads: its file's ``dictionary`` line, else its language's."""
    return _voice_setting(data / "lang" / identifier, "dictionary") or code.split("-")[0]


def _voice_setting(path: Path, key: str) -> str:
    """The value of the last ``key value`` line of an espeak-ng voice file ("" without one)."""
    value = ""
    if path.is_file():
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
            words = line.split()
            if len(words) >= 2 and words[0] == key:
                value = words[1]
    return value


def find_language(code: str) -> Language:
    """The language of a code (any case, or one of its aliases); :class:`VispeechError` naming
    the command that lists them."""
    wanted = str(code).strip().lower()
    for language in languages():
        if language.code == wanted or wanted in language.aliases:
            return language
    raise VispeechError(
        f"unknown language {code!r}: `vispeech languages` lists the {len(languages())} espeak-ng speaks"
    )


def phone_set(language: str) -> str:
    """The phone set a language's phones come in: ``sv``, ``en`` or ``ipa`` (every other language)."""
    return find_language(language).phones


@cache
def voices() -> dict[str, str]:
    """The voices any language can be spoken with: espeak-ng's voice variants (``f1``-``f5``
    female, ``m1``-``m8`` male, ``klatt``, ``whisper`` ...), name -> gender (``female``,
    ``male`` or ``""``), from the files of ``espeak-ng-data/voices/!v``."""
    import espeakng_loader

    folder = Path(espeakng_loader.get_data_path()) / "voices" / "!v"
    paths = sorted(folder.iterdir()) if folder.is_dir() else []
    return {path.name: _voice_setting(path, "gender") for path in paths if path.is_file() and " " not in path.name}


def check_voice(voice: str | None) -> str | None:
    """``voice`` if it is one of :func:`voices` (or ``None``); :class:`VispeechError` otherwise."""
    if voice is None or voice in voices():
        return voice
    raise VispeechError(
        f"unknown voice {voice!r}: `vispeech languages --voices` lists them (f1-f5 female, m1-m8 male, ...)"
    )


def synthesize(
    text: str, language: str = "en", rate: float = 1.0, *, voice: str | None = None, reproducible: bool = True
) -> Speech:
    """Speak ``text`` with espeak-ng and return the audio with its phones and words.

    ``language`` is a code of :func:`languages`: ``"sv"`` and ``"en"`` (voice file ``en-us``)
    give phones of the curated inventories, every other language IPA phones. ``voice`` is one
    of :func:`voices` (``None``: the language's own). ``rate`` is a speaking-rate
    factor (1.0 = 175 words per minute, from 0.5 to 2.5). The phones cover ``[0, duration]``
    exactly. ``reproducible=False`` saves about 7 ms by reusing the library loaded by the last
    such call, at the price of samples and phone onsets that depend on what was spoken before
    (see the module docstring). A crash or hang of espeak-ng on the text is a
    :class:`~vispeech.errors.NativeFailure`.
    """
    spoken = find_language(language)
    check_voice(voice)
    ipa = spoken.phones == IPA
    if not text or not text.strip():
        raise VispeechError("text is empty")
    try:
        factor = float(rate)
    except (TypeError, ValueError):
        factor = math.nan
    if not MIN_RATE <= factor <= MAX_RATE:
        raise VispeechError(f"rate must be between {MIN_RATE} and {MAX_RATE}, got {rate!r}")
    selector = spoken.selector if voice is None else f"{spoken.selector}+{voice}"
    samples, events, sample_rate = run_isolated(
        "espeak-ng",
        f"this text in language {spoken.code}",
        _speak,
        text,
        selector,
        round(DEFAULT_WPM * factor),
        ipa,
        reproducible,
    )
    if len(samples) == 0:
        raise VispeechError("espeak-ng produced no audio for this text")
    audio = samples.astype(np.float32) / 32768.0
    phones = _phone_sequence(text, events, len(audio), sample_rate, spoken.phones, spoken.code)
    return Speech(audio=audio, sample_rate=sample_rate, phones=phones)


def _speak(text: str, selector: str, wpm: int, ipa: bool, reproducible: bool) -> tuple[np.ndarray, list[tuple], int]:
    """In a worker process: espeak-ng's samples (int16), events and sample rate for ``text``."""
    global _engine
    with _lock:
        if _engine is not None and (reproducible or _engine.ipa != ipa):  # unload to start afresh
            _engine.close()
            _engine = None
        engine = _engine or _Engine(ipa)
        try:
            samples, events = engine.synthesize(text, selector, wpm)
        finally:
            if reproducible:
                engine.close()
            else:
                _engine = engine
        return samples, events, engine.sample_rate


def _phone_sequence(
    text: str, events: list[tuple], n_samples: int, sample_rate: int, language: str, spoken: str
) -> PhoneSequence:
    """Turn espeak's word and phoneme events into a gap-free, validated phone sequence.

    ``language`` is the phone set, ``spoken`` the language code (for warnings)."""
    # A word is a blank-separated token of the text. espeak may read one token as several
    # words ("1,000,000", "iPhone") and reports their positions loosely: each word event
    # goes to the token its position falls in (or the one before, on a blank).
    tokens = [match.span() for match in re.finditer(r"\S+", text)]
    token_starts = [start for start, _ in tokens]
    spans: list[tuple[int, int]] = []  # character range of each word in ``text``
    onsets: list[tuple[int, str, str, int | None]] = []  # sample, espeak name, phoneme table, word
    table = language
    for event in events:
        if event[0] == "word":
            token = tokens[max(bisect.bisect_right(token_starts, event[2] - 1) - 1, 0)]
            if not spans or spans[-1] != token:
                spans.append(token)
            continue
        name = event[2]
        if name.startswith("(") and name.endswith(")"):  # switch of phoneme table, e.g. "(en)"
            table = name[1:-1].split("-")[0]
        elif name != ";":  # ";" palatalises the phone before it
            sample = min(max(event[1], onsets[-1][0] if onsets else 0), n_samples)
            onsets.append((sample, name, table, len(spans) - 1 if spans else None))

    phones: list[Phone] = []
    for i, (start, name, table, word) in enumerate(onsets):
        stop = onsets[i + 1][0] if i + 1 < len(onsets) else n_samples
        if language == IPA:
            try:
                pairs = espeak_ipa_to_symbols(name)
            except VispeechError:
                warnings.warn(
                    f"espeak-ng phoneme {name!r} ({spoken}) has no IPA phone; it joins the phone before it",
                    PhoneWarning,
                    stacklevel=3,
                )
                pairs = ()
            if not pairs:  # a length mark of its own, or an unknown phoneme: the phone before lasts
                if phones and stop > start:
                    phones[-1] = replace(phones[-1], end=stop / sample_rate)
                continue
        else:
            pairs = espeak_to_symbols(name, language, table)
        for k, (symbol, stress) in enumerate(pairs):  # r-coloured vowels: equal parts
            a = start + (stop - start) * k / len(pairs)
            b = start + (stop - start) * (k + 1) / len(pairs)
            if b > a:
                owner = None if is_silence(symbol) else word
                phones.append(Phone(symbol, a / sample_rate, b / sample_rate, owner, stress))
    if language == "sv":
        phones = _merge_retroflexes(phones)
    phones = PhoneSequence(phones=phones, language=language).with_gaps_filled().phones
    end = n_samples / sample_rate
    if not phones or phones[-1].end < end:
        phones.append(Phone(SILENCE, phones[-1].end if phones else 0.0, end))
    phones = _merge_silences(phones)

    # keep the words that got phones, renumbered, each from its first phone to its last
    words: list[Word] = []
    renumber: dict[int, int] = {}
    for p in phones:
        if p.word is None:
            continue
        if p.word not in renumber:
            renumber[p.word] = len(words)
            start, stop = spans[p.word]
            spoken = text[start:stop].strip()
            words.append(Word(spoken.strip(_PUNCTUATION) or spoken, p.start, p.end))
        words[renumber[p.word]] = replace(words[renumber[p.word]], end=p.end)
    phones = [p if p.word is None else replace(p, word=renumber[p.word]) for p in phones]
    return PhoneSequence(phones=phones, language=language, words=words).validate()


def _merge_retroflexes(phones: list[Phone]) -> list[Phone]:
    """Swedish ``r`` + ``t d n l s`` within one word -> ``rt rd rn rl rs`` spanning both."""
    merged: list[Phone] = []
    for p in phones:
        last = merged[-1] if merged else None
        if (
            last is not None
            and last.symbol == "r"
            and p.symbol in _RETROFLEX
            and p.word is not None
            and last.word == p.word
            and abs(last.end - p.start) < TIME_TOLERANCE
        ):
            merged[-1] = replace(p, symbol=_RETROFLEX[p.symbol], start=last.start)
        else:
            merged.append(p)
    return merged


def _merge_silences(phones: list[Phone]) -> list[Phone]:
    """Join adjacent silences into one ``sil``."""
    merged: list[Phone] = []
    for p in phones:
        if merged and is_silence(p.symbol) and is_silence(merged[-1].symbol):
            merged[-1] = replace(merged[-1], symbol=SILENCE, end=p.end)
        else:
            merged.append(p)
    return merged
