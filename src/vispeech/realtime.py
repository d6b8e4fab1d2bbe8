"""Realtime voice services: their audio with the timings they give (characters, words or visemes
with times) animated by a phone model as both arrive (:class:`TimedSpeechStream`), the engine of
``/api/listen`` when a stream declares its timings."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, Word
from vispeech.errors import VispeechError
from vispeech.frontends.audio import check_sample_rate
from vispeech.frontends.timings import (
    LAST_VISEME_SECONDS,
    characters_to_words,
    phones_over_visemes,
    phones_over_words,
    viseme_phone,
)
from vispeech.limits import check_fps
from vispeech.models.contract import Estimator
from vispeech.phonetics.inventory import SILENCE
from vispeech.pipeline import DEFAULT_FPS
from vispeech.postprocess.rest import SentFrames
from vispeech.streaming import MAX_PHONE_SECONDS, PhoneStream

TIMINGS = ("characters", "words", "visemes")
"""The timings a :class:`TimedSpeechStream` takes: ElevenLabs-style characters with times, words
with times (Azure's word boundaries), visemes with times (Azure's ids, Oculus's names)."""


class TimedSpeechStream:
    """Frames for a voice service's audio that comes with its own timings: characters, words or
    visemes with times (:data:`TIMINGS`) become timed phones (:mod:`vispeech.frontends.timings`),
    which a :class:`PhoneStream` of a phone model animates; the audio (16-bit PCM chunks, as
    :class:`LiveAudioStream` takes them) only tells how long the stream lasts.

    Frames come as soon as the timings cover them (:attr:`lookahead` frames after), whether the
    audio they describe has come or not: timings ahead of their audio give frames ahead of it,
    timings behind it hold its frames back until they come. Words are complete at once,
    characters at the white space after them, a viseme lasts until the next one, so the last word
    of characters and the last viseme wait for the next message or :meth:`finish`. :meth:`finish`
    completes them (the last viseme lasting to the audio's end, at least
    :data:`~vispeech.frontends.timings.LAST_VISEME_SECONDS`) and fills the time up to the audio's
    end with silence: the frames equal :func:`~vispeech.pipeline.animate` of the same phones
    (:func:`~vispeech.frontends.timings.timed_word_phones` for words) but for the phone stream's
    windowed post-processing. Words and characters are read in ``language`` (espeak-ng's phones of
    each word), visemes as English phones.
    """

    def __init__(
        self, model: Estimator, timings: str, sample_rate: int, language: str = "en", fps: float = DEFAULT_FPS
    ) -> None:
        from vispeech.frontends.espeak import phone_set

        if model.input_kind != "phones":
            raise VispeechError(f"model {model.name} animates audio: timings need a model that animates phones")
        if timings not in TIMINGS:
            raise VispeechError(f"unknown timings {timings!r} (use {', '.join(TIMINGS)})")
        self.timings = timings
        self.language = language
        self.sample_rate = check_sample_rate(sample_rate)
        self._phones = PhoneStream(model, "en" if timings == "visemes" else phone_set(language), check_fps(fps))
        self.fps = self._phones.fps
        self.channels = self._phones.channels
        self.lookahead = self._phones.lookahead
        self.samples = 0
        """Samples received so far, at :attr:`sample_rate`."""
        self._characters: list[tuple[str, float, float]] = []  # of the word not yet complete
        self._viseme: tuple[int | str, float] | None = None  # the viseme whose end is not yet known
        self.sent = SentFrames(len(self.channels), self.fps)

    @property
    def duration(self) -> float:
        """Seconds of audio received so far."""
        return self.samples / self.sample_rate

    @property
    def emitted(self) -> int:
        """Frames given so far."""
        return self._phones.emitted

    @property
    def closed(self) -> bool:
        return self._phones.closed

    @property
    def end(self) -> float:
        """Seconds the timings animated so far reach (the last complete word's end, the last viseme's start)."""
        return self._phones.end

    def push(self, pcm: bytes) -> tuple[int, np.ndarray]:
        """Add a chunk of PCM bytes (counted, not heard): no frames."""
        if self.closed:
            raise VispeechError("this audio stream has ended")
        if len(pcm) % 2:
            raise VispeechError(f"16-bit PCM has 2 bytes a sample: a chunk of {len(pcm)} bytes is cut short")
        self.samples += len(pcm) // 2
        return self.emitted, np.zeros((0, len(self.channels)))

    def add_words(self, words: Sequence[Word]) -> tuple[int, np.ndarray]:
        """Add timed words; the frames that became ready."""
        self._expect("words")
        return self._push(phones_over_words(words, self.language, self._phones.end))

    def add_characters(
        self, characters: Sequence[str], starts: Sequence[float], ends: Sequence[float]
    ) -> tuple[int, np.ndarray]:
        """Add timed characters; the frames that the words they complete made ready."""
        self._expect("characters")
        characters_to_words(characters, starts, ends)  # as many times as characters
        held = self._characters + list(zip(characters, starts, ends))
        complete = max((k + 1 for k, (char, _, _) in enumerate(held) if not char.strip()), default=0)
        words = characters_to_words(*_columns(held[:complete]))
        out = self._push(phones_over_words(words, self.language, self._phones.end))
        self._characters = held[complete:]
        return out

    def add_visemes(self, visemes: Sequence[tuple[int | str, float]]) -> tuple[int, np.ndarray]:
        """Add timed visemes; the frames that became ready."""
        self._expect("visemes")
        held = ([self._viseme] if self._viseme is not None else []) + list(visemes)
        if not held:
            return self.emitted, np.zeros((0, len(self.channels)))
        for (_, before), (viseme, time) in zip(held, held[1:]):
            if time < before:
                raise VispeechError(
                    f"viseme {viseme!r} at {time:.3f} s comes before the one before it ({before:.3f} s)"
                )
        viseme_phone(held[-1][0])  # known, though its end is not
        out = self._push(phones_over_visemes(held[:-1], held[-1][1], self._phones.end))
        self._viseme = held[-1]
        return out

    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed, up to the audio's end (or the timings', if later)."""
        if self.closed:
            raise VispeechError("this audio stream has ended")
        begin = self._phones.end
        if self._viseme is not None:
            end = max(self.duration, self._viseme[1] + LAST_VISEME_SECONDS)
            phones = phones_over_visemes([self._viseme], end, begin)
        else:
            phones = phones_over_words(characters_to_words(*_columns(self._characters)), self.language, begin)
        time = phones[-1].end if phones else begin
        if self.duration > time + TIME_TOLERANCE:  # silence to the audio's end
            phones.append(Phone(SILENCE, time, self.duration))
        start, rows = self._push(phones)
        rest = self._kept(*self._phones.finish())[1]
        return start, np.concatenate([rows, rest])

    def cancel(self, frame: int | None = None) -> tuple[int, np.ndarray]:
        """End the stream at once (the listener interrupted), or after it ended: the frames easing
        the face to rest from frame ``frame`` (``None``: the last given), after it
        (:meth:`~vispeech.postprocess.rest.SentFrames.ease`)."""
        self.close()
        return self.sent.ease(frame)

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self._phones.close()

    def _expect(self, timings: str) -> None:
        if self.closed:
            raise VispeechError("this audio stream has ended")
        if timings != self.timings:
            raise VispeechError(f"this audio stream takes {self.timings}, not {timings}")

    def _push(self, phones: list[Phone]) -> tuple[int, np.ndarray]:
        """Push ``phones``, a pause longer than a phone stream's step (:data:`MAX_PHONE_SECONDS`) in pieces."""
        pieces = []
        for phone in phones:
            time = phone.start
            while phone.is_silence and phone.end - time > MAX_PHONE_SECONDS:
                pieces.append(Phone(SILENCE, time, time + MAX_PHONE_SECONDS / 2))
                time = pieces[-1].end
            pieces.append(Phone(phone.symbol, time, phone.end, phone.word, phone.stress))
        return self._kept(*self._phones.push(pieces))

    def _kept(self, start: int, rows: np.ndarray) -> tuple[int, np.ndarray]:
        """``(start, rows)``, the rows kept for :meth:`cancel`."""
        self.sent.add(rows)
        return start, rows


def _columns(characters: list[tuple[str, float, float]]) -> tuple[list[str], list[float], list[float]]:
    """Timed characters as their three columns."""
    return [c for c, _, _ in characters], [a for _, a, _ in characters], [b for _, _, b in characters]
