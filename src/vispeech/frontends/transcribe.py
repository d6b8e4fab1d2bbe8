"""Speech to text offline for audio that comes without its transcript: Whisper through
faster-whisper (the ``whisper`` extra), its words made ready for forced alignment.

``vispeech animate AUDIO --transcribe`` takes this path, in Python ``listen(clip,
transcribe(clip, language), language)`` (:func:`vispeech.pipeline.listen`): the audio →
:func:`transcribe` → forced alignment (:func:`vispeech.frontends.align.align`) → a phone
model, as with a transcript given.

**Models.** English (``en`` and its varieties) is transcribed by ``whisper-tiny.en``, every
other language by ``whisper-base`` with the language given, never detected: the named models of
:mod:`vispeech.frontends.whisper` (``$VISPEECH_WHISPER_MODEL`` replaces both). faster-whisper
runs them on the CPU in int8 on :data:`~vispeech.frontends.whisper.THREADS` threads, in a
worker process (:mod:`vispeech.frontends.isolation`: a crash of CTranslate2 or a hang is a
:class:`~vispeech.errors.NativeFailure`), each folder loaded once per worker and shared
between threads; only the local folder is read
(a folder without ``tokenizer.json`` is refused: faster-whisper would fetch one).

**Decoding.** Silero VAD (shipped inside faster-whisper) drops what is not speech first: on
silence or music Whisper writes words nobody said ("Thank you."). Then beam search of
:data:`BEAM_SIZE` at temperature 0, each 30-s window decoded on its own (not conditioned on
the text before it, which carries a hallucination on), without faster-whisper's fallback to
sampling at higher temperatures and with at most :data:`TOKENS_PER_SECOND` tokens per second
of a window: a window that loops stops there, so the time a clip takes stays bounded (the
fallback took up to 35 s on a 3-s clip of espeak-ng's Swedish voice).

**Text for the aligner** (:func:`aligner_text`). Non-speech annotations (``[Music]``,
``(laughs)``, ``♪``) go in every language. English is aligned by pocketsphinx, whose CMU
dictionary must know every word, so: hyphens, dashes and slashes split words; ``&`` is
"and"; numbers are spelled out (``1,250`` one thousand two hundred fifty, ``2009`` two
thousand nine and ``1984`` nineteen eighty four as years, ``20th``, ``60s``, ``3.5`` three
point five, ``%``, ``$``, ``£``, ``€``); acronyms are spelled as letters (``D.C.``, ``BP``,
``AI``: dotted, of two or three capitals, or of more capitals that the dictionary lacks); a
possessive the dictionary lacks keeps its word (``Kylie's`` → ``kylie`` if known); every
other word the dictionary lacks is **dropped** (the aligner spreads the neighbouring words
or silence over its sound). On the 14 natural clips of ``dev_eval`` nothing was left to
drop once the numbers were spelled. Swedish and the other languages are aligned against
espeak-ng (:mod:`vispeech.frontends.dtw_align`), which reads whatever espeak-ng reads
(digits included), so their text is kept as Whisper wrote it.

**A second opinion on a transcript** (:func:`second_opinion`). pocketsphinx's fit
(:func:`vispeech.frontends.align.transcript_fit`) refuses some true transcripts of voices far
from its acoustic model (espeak-ng's variant voices: 16 of 32); where the ``whisper`` extra is
installed, :func:`vispeech.pipeline.hear` then asks Whisper, and takes an English transcript
that Whisper hears with a word error rate of at most :data:`MAX_HEARD_WER`.
"""

from __future__ import annotations

import math
import re
import threading
from pathlib import Path

import numpy as np

from vispeech.alignment.edits import edit_path
from vispeech.errors import NativeFailure, VispeechError
from vispeech.frontends.align import EDGE_PUNCTUATION, in_dictionary
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.isolation import run_isolated
from vispeech.frontends.whisper import INSTALL, SAMPLE_RATE, THREADS, model_folder, per_process

ENGLISH_MODEL = "whisper-tiny.en"
"""The Whisper model that transcribes English."""
MULTILINGUAL_MODEL = "whisper-base"
"""The Whisper model that transcribes every other language (Swedish included)."""
BEAM_SIZE = 5
"""Hypotheses the beam search keeps."""
TOKENS_PER_SECOND = 10
"""The most tokens decoded per second of a window (fluent English needs about 5), plus
:data:`EXTRA_TOKENS`."""
EXTRA_TOKENS = 20
"""Tokens allowed on top of :data:`TOKENS_PER_SECOND` in every window."""
WINDOW_SECONDS = 30.0
"""The audio Whisper reads at once (s)."""
MAX_DIGITS = 15
"""Longer numbers are read digit by digit."""
MAX_HEARD_WER = 1 / 3
"""The most words in three that Whisper may hear otherwise for :func:`second_opinion` to take an
English transcript: one. Wrong transcripts of grid_s1 clips (60, each with the next clip's
transcript, three of six words shared at most) were heard at 0.5 and above, those of espeak-ng's
voices at 0.89 and above; of the 16 true transcripts of espeak-ng's voices that the fit refused,
10 were heard within it (docs/audio.md)."""

_LOAD_LOCK = threading.Lock()
_ANNOTATION = re.compile(r"\[[^\]]*\]|\([^)]*\)|\*[^*]*\*|[♪♫]")
_WORD_BREAK = re.compile(r"[\s\-‐‑–—/]+")
_NUMBER = re.compile(r"([$£€]?)(\d{1,3}(?:,\d{3})+|\d+)(?:\.(\d+))?(st|nd|rd|th|s|'s)?(%?)")
_CURRENCY = {"$": ("dollars", "cents"), "£": ("pounds", "pence"), "€": ("euros", "cents")}
_ONES = (
    "zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen "
    "sixteen seventeen eighteen nineteen"
).split()
_TENS = "_ _ twenty thirty forty fifty sixty seventy eighty ninety".split()
_SCALES = ((10**12, "trillion"), (10**9, "billion"), (10**6, "million"), (1000, "thousand"))
_ORDINALS = {
    "one": "first",
    "two": "second",
    "three": "third",
    "five": "fifth",
    "eight": "eighth",
    "nine": "ninth",
    "twelve": "twelfth",
}
_WHISPER_CODES = {"cmn": "zh", "nb": "no"}
"""espeak-ng's language codes that Whisper names otherwise."""


def transcribe(clip: AudioClip, language: str = "en", model: str | None = None) -> str:
    """The words spoken in ``clip``, in ``language``, as the aligner reads them (:func:`aligner_text`).

    ``model`` is a Whisper model name or folder (:func:`~vispeech.frontends.whisper.model_folder`);
    by default :data:`ENGLISH_MODEL` for English and :data:`MULTILINGUAL_MODEL` otherwise.
    Raises :class:`VispeechError` (one line) when the ``whisper`` extra is missing, the model
    cannot load or does not speak ``language``, or no words are heard.
    """
    code = language.split("-")[0]
    code = _WHISPER_CODES.get(code, code)
    folder = model_folder(model or (ENGLISH_MODEL if code == "en" else MULTILINGUAL_MODEL))
    _whisper_class()  # a missing extra is told here, before any worker
    samples = clip.resampled(SAMPLE_RATE).samples
    heard = run_isolated(
        "faster-whisper", "this recording", _heard, str(folder), samples, language, code, extra_time=clip.duration
    )
    text = aligner_text(heard, language)
    if not text:
        raise VispeechError("no words recognised in the audio" + (f" (Whisper heard {heard[:80]!r})" if heard else ""))
    return text


def second_opinion(clip: AudioClip, text: str) -> tuple[bool, str | None]:
    """Whether Whisper (:data:`ENGLISH_MODEL`) hears the English ``text`` in ``clip``: its word
    error rate against what Whisper heard (both as :func:`aligner_text` makes them) is at most
    :data:`MAX_HEARD_WER`; and what it heard (``""``: no words; ``None``: nothing to say, as the
    ``whisper`` extra is not installed or Whisper failed on the clip, and the answer is ``False``)."""
    from vispeech.frontends.whisper import installed

    if not installed(ENGLISH_MODEL):
        return False, None
    try:
        heard = transcribe(clip, "en")
    except NativeFailure:
        return False, None
    except VispeechError:
        return False, ""
    expected = aligner_text(text, "en")
    return bool(expected) and word_error_rate(expected, heard) <= MAX_HEARD_WER, heard


def aligner_text(text: str, language: str) -> str:
    """``text`` as Whisper wrote it, made ready for :func:`vispeech.frontends.align.align` in
    ``language`` (see the module docstring): in English lower-case words of the CMU dictionary,
    separated by single spaces; in other languages the text without non-speech annotations.
    Empty when nothing speakable is left."""
    text = _ANNOTATION.sub(" ", text.replace("’", "'"))
    if language != "en":
        return " ".join(text.split())
    tokens = _WORD_BREAK.split(text.replace("&", " and "))
    words = [word for token in tokens for word in _english_words(token.strip(EDGE_PUNCTUATION))]
    return " ".join(word for word in words if in_dictionary(word))


def _english_words(token: str) -> list[str]:
    """The dictionary words one token of English text stands for (none: dropped)."""
    if not token:
        return []
    number = _NUMBER.fullmatch(token)
    if number:
        return _spoken_number(*number.groups())
    if any(c.isdigit() for c in token):  # "3:15", "G0", "mp3": letters and numbers in turn
        return [w for part in re.findall(r"[^\W\d_]+|\d+", token) for w in _english_words(part)]
    word, letters = token.lower(), [c for c in token.lower() if c.isalpha()]
    capitals = token.isupper() and len(letters) > 1
    if "." in word or (capitals and (len(letters) <= 3 or not in_dictionary(word))):
        return letters
    if not in_dictionary(word) and word.endswith("'s") and in_dictionary(word[:-2]):
        return [word[:-2]]
    return [word]


def _spoken_number(currency: str, whole: str, decimals: str | None, suffix: str | None, percent: str) -> list[str]:
    """The words of a number token split by ``_NUMBER``: ``$``, ``1,250``, ``.5``, ``th``/``s``, ``%``."""
    digits = whole.replace(",", "")
    if len(digits) > MAX_DIGITS:
        return [_ONES[int(d)] for d in digits]
    value = int(digits)
    year = (
        not currency
        and decimals is None
        and "," not in whole
        and suffix in (None, "s", "'s")
        and (1100 <= value <= 1999 or 2010 <= value <= 2099)
    )
    words = _year(value) if year else _cardinal(value)
    if suffix in ("st", "nd", "rd", "th"):
        words[-1] = _ORDINALS.get(words[-1]) or (
            words[-1][:-1] + "ieth" if words[-1].endswith("y") else words[-1] + "th"
        )
    elif suffix in ("s", "'s"):
        last = words[-1]
        words[-1] = last[:-1] + "ies" if last.endswith("y") else last + ("es" if last.endswith("x") else "s")
    tail = ["percent"] if percent else []
    if currency:
        unit, hundredth = _CURRENCY[currency]
        if decimals is not None and len(decimals) == 2:  # $19.99: nineteen dollars ninety nine cents
            cents = int(decimals)
            return words + [unit] + (_cardinal(cents) + [hundredth] if cents else [])
        tail = [unit, *tail]
    if decimals is not None:
        words += ["point"] + [_ONES[int(d)] for d in decimals]
    return words + tail


def _cardinal(n: int) -> list[str]:
    """``n`` (≥ 0) in words: 1,250 → one thousand two hundred fifty."""
    if n < 20:
        return [_ONES[n]]
    if n < 100:
        return [_TENS[n // 10]] + ([_ONES[n % 10]] if n % 10 else [])
    if n < 1000:
        return [_ONES[n // 100], "hundred"] + (_cardinal(n % 100) if n % 100 else [])
    scale, name = next((s, name) for s, name in _SCALES if n >= s)
    return _cardinal(n // scale) + [name] + (_cardinal(n % scale) if n % scale else [])


def _year(n: int) -> list[str]:
    """A year as it is said: 1984 nineteen eighty four, 1905 nineteen oh five, 1900 nineteen hundred."""
    high, low = divmod(n, 100)
    return _cardinal(high) + (["hundred"] if low == 0 else ["oh", _ONES[low]] if low < 10 else _cardinal(low))


def words_of(text: str) -> list[str]:
    """The words of ``text`` as :func:`word_error_rate` compares them: lower case, split at
    white space, hyphens, dashes and slashes, punctuation stripped from their ends."""
    tokens = _WORD_BREAK.split(text.replace("’", "'"))
    return [w for w in (token.strip(EDGE_PUNCTUATION).lower() for token in tokens) if w]


def word_error_rate(reference: str, hypothesis: str) -> float:
    """Substituted, inserted and deleted words (:func:`words_of`) over the reference's words;
    :class:`VispeechError` for a reference without words."""
    expected = words_of(reference)
    if not expected:
        raise VispeechError("the reference transcript has no words")
    return edit_path(expected, words_of(hypothesis))[0] / len(expected)


def _heard(folder: str, samples: np.ndarray, language: str, code: str) -> str:
    """In a worker process: what the Whisper model in ``folder`` hears in ``samples`` (16 kHz) in
    ``language`` (Whisper's ``code`` for it), as it writes it."""
    whisper = _whisper_model(folder)
    if code not in whisper.supported_languages:
        only = " (it transcribes English only)" if whisper.supported_languages == ["en"] else ""
        raise VispeechError(f"Whisper model {folder} cannot transcribe language {language!r}{only}")
    window = min(max(len(samples) / SAMPLE_RATE, 0.0), WINDOW_SECONDS)
    segments, _ = whisper.transcribe(
        samples,
        language=code,
        beam_size=BEAM_SIZE,
        temperature=0.0,
        condition_on_previous_text=False,
        vad_filter=True,
        max_new_tokens=math.ceil(TOKENS_PER_SECOND * window) + EXTRA_TOKENS,
    )
    return " ".join(segment.text.strip() for segment in segments)


def _whisper_class():
    """faster-whisper's ``WhisperModel``; :class:`VispeechError` when the extra is missing."""
    try:
        from faster_whisper import WhisperModel
    except ImportError:
        raise VispeechError(f"transcription needs faster-whisper: {INSTALL}") from None
    return WhisperModel


def _whisper_model(folder: str):
    """faster-whisper's model of a CTranslate2 Whisper folder, loaded once per process."""
    with _LOAD_LOCK:
        return _load(folder)


@per_process
def _load(folder: str):
    whisper_model = _whisper_class()
    if not (Path(folder) / "tokenizer.json").is_file():
        raise VispeechError(f"Whisper model {folder} has no tokenizer.json (faster-whisper would download one)")
    try:
        return whisper_model(folder, device="cpu", compute_type="int8", cpu_threads=THREADS, local_files_only=True)
    except (OSError, ValueError, RuntimeError) as exc:
        raise VispeechError(f"cannot load Whisper model {folder}: {str(exc).splitlines()[0]}") from None
