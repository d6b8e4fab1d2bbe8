"""Forced alignment of English speech with its transcript, by pocketsphinx.

The pocketsphinx wheel ships the en-us acoustic model and CMUdict, so nothing is downloaded.
Phones come as ARPAbet without stress (the shipped dictionary has no stress digits, so every
phone gets ``stress=0``) and silences as ``sil``.
"""

from __future__ import annotations

import functools
import math
import re
import threading

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.phonetics.inventory import SILENCE, parse_symbol

SAMPLE_RATE = 16000
"""The acoustic model's sample rate in Hz; other rates are resampled to it."""

PAD_SECONDS = 0.5
"""Silence added before and after the audio: without it the first decoding pass can fail."""

FRAMES_PER_SECOND = 100
"""pocketsphinx reports times in 10 ms frames."""

ALIGNER = "pocketsphinx 5.1.1"
"""Names the aligner in cached results, so that a change of aligner invalidates them."""

_EDGE_PUNCTUATION = "\"'.,;:!?()[]{}«»“”‘’—–-"
_ALTERNATE = re.compile(r"\(\d+\)$")
_DECODER_LOCK = threading.Lock()  # one shared decoder per process


def align(audio: np.ndarray, sample_rate: int, text: str, language: str = "en") -> PhoneSequence:
    """Time-align ``text`` with ``audio``: phones and words with start/end in seconds.

    ``audio`` holds samples (float in [-1, 1] or int16), mono or ``(samples, channels)``
    (channels are averaged) at ``sample_rate`` Hz. The result covers the whole audio: silence
    before, between and after words is ``sil``. Raises :class:`VispeechError` for a language
    other than ``"en"``, words missing from the pronouncing dictionary (named), empty text or
    audio, or a failed alignment.
    """
    if language != "en":
        raise VispeechError(f"forced alignment supports English only (language 'en'), not {language!r}")
    words = normalize_transcript(text)
    decoder = _decoder()
    unknown = [w for w in dict.fromkeys(words) if decoder.lookup_word(w) is None]
    if unknown:
        raise VispeechError(f"words not in the pronouncing dictionary: {', '.join(unknown)}")
    samples = _to_pcm16(audio, sample_rate)
    duration = len(samples) / SAMPLE_RATE
    pad = np.zeros(int(PAD_SECONDS * SAMPLE_RATE), dtype=np.int16)
    raw = np.concatenate([pad, samples, pad]).tobytes()
    try:
        with _DECODER_LOCK:
            decoder.set_align_text(" ".join(words))
            _decode(decoder, raw)
            decoder.set_alignment()
            _decode(decoder, raw)
            segments = [(w.name, [(p.name, p.start, p.duration) for p in w]) for w in decoder.get_alignment()]
    except RuntimeError as exc:
        raise VispeechError(f"alignment failed for {text!r}: {exc}") from None
    if not segments:
        raise VispeechError(f"alignment failed for {text!r}: no result")
    return _to_phone_sequence(segments, duration)


def normalize_transcript(text: str) -> list[str]:
    """Lower-case words of ``text`` with punctuation stripped from their edges."""
    words = [w.strip(_EDGE_PUNCTUATION).lower() for w in text.split()]
    words = [w for w in words if w]
    if not words:
        raise VispeechError("the transcript has no words")
    return words


@functools.cache
def _decoder():
    from pocketsphinx import Decoder

    return Decoder(
        samprate=SAMPLE_RATE, lm=None, bestpath=False, beam=1e-100, wbeam=1e-80, pbeam=1e-100,
        loglevel="FATAL",
    )


def _decode(decoder, raw: bytes) -> None:
    decoder.start_utt()
    decoder.process_raw(raw, full_utt=True)
    decoder.end_utt()


def _to_pcm16(audio: np.ndarray, sample_rate: int) -> np.ndarray:
    samples = np.asarray(audio)
    if samples.ndim == 2:
        samples = samples.mean(axis=1)
    if samples.ndim != 1 or samples.size == 0:
        raise VispeechError(f"audio must be a non-empty 1-D or (samples, channels) array, got shape {np.shape(audio)}")
    if sample_rate <= 0:
        raise VispeechError(f"sample rate must be positive, got {sample_rate}")
    if np.issubdtype(samples.dtype, np.integer):
        samples = samples.astype(np.float64) / 32768.0
    samples = samples.astype(np.float64)
    if not np.all(np.isfinite(samples)):
        raise VispeechError("audio has non-finite samples")
    if sample_rate != SAMPLE_RATE:
        from scipy.signal import resample_poly

        g = math.gcd(int(sample_rate), SAMPLE_RATE)
        samples = resample_poly(samples, SAMPLE_RATE // g, int(sample_rate) // g)
    return np.round(np.clip(samples, -1.0, 1.0) * 32767).astype(np.int16)


def _to_phone_sequence(segments: list[tuple[str, list[tuple[str, int, int]]]], duration: float) -> PhoneSequence:
    """Words and phones from pocketsphinx frames: pad removed, clipped to the audio, silences merged."""
    offset = round(PAD_SECONDS * FRAMES_PER_SECOND)
    words: list[Word] = []
    phones: list[Phone] = []
    for name, word_phones in segments:
        word_index = None
        if not name.startswith(("<", "[")):
            word_index = len(words)
        for label, start_frame, n_frames in word_phones:
            start = min(max((start_frame - offset) / FRAMES_PER_SECOND, 0.0), duration)
            end = min(max((start_frame + n_frames - offset) / FRAMES_PER_SECOND, 0.0), duration)
            if end - start < TIME_TOLERANCE:
                continue
            symbol, stress = parse_symbol(label, "en")
            if symbol == SILENCE and phones and phones[-1].symbol == SILENCE:
                phones[-1] = Phone(SILENCE, phones[-1].start, end)
                continue
            phones.append(Phone(symbol, start, end, None if symbol == SILENCE else word_index, stress))
        if word_index is not None:
            own = [p for p in phones if p.word == word_index]
            if not own:
                raise VispeechError(f"alignment failed: word {name!r} lies outside the audio")
            words.append(Word(_ALTERNATE.sub("", name), own[0].start, own[-1].end))
    if phones and phones[-1].end < duration - TIME_TOLERANCE:
        phones.append(Phone(SILENCE, phones[-1].end, duration))
    return PhoneSequence(phones, "en", words).validate()
