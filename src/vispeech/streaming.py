"""Streaming animation: text spoken clause by clause, and frames for phones as they arrive.

**Text.** :func:`speech_messages` splits the text into sentences and clauses (after
``. ! ? ; : , …`` followed by white space, and at line breaks), synthesises and animates each
in turn and gives the ``/api/stream`` protocol messages for it at once, so the first frames
and audio leave after the first clause, not after the whole text. The clauses follow each
other on one timeline: frame k sits at ``k / fps`` seconds from the start of the first
clause's audio, and a frame that falls between two clauses' frame grids is interpolated
from its own clause's track. Audio goes in pieces of ``chunk_seconds`` (PCM16, base64), each
preceded by the frames up to its end.

**Phones.** :func:`open_phone_stream` takes timed phones as a recogniser or a TTS engine
emits them and gives each frame as soon as it may be computed:

- a model with ``predict_stream`` (the low-latency network, ``tdnn-lowlatency``) runs its own
  streaming prediction at its own frame rate, frame t leaving once the phones covering
  ``t + look_ahead`` frames are known (:class:`ModelPhoneStream`);
- any other model gives frame t once phones cover frame ``t + lookahead`` (default 2) by
  re-predicting a bounded recent window: the phones of the last ``context`` seconds (0.5)
  before the first frame not yet sent, up to the latest phone end, with the default
  post-processing (:class:`WindowPhoneStream`).
"""

from __future__ import annotations

import base64
import math
import queue
import re
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import replace

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence, n_frames_for
from vispeech.errors import VispeechError
from vispeech.models.contract import ControlModel
from vispeech.phonetics.inventory import SILENCE, parse_symbol
from vispeech.pipeline import DEFAULT_FPS, animate

MAX_PHONE_SECONDS = 10.0
"""Longest step (seconds) from one phone's end to the next's in a phone stream."""

_CLAUSE_BREAK = re.compile(r"(?<=[.!?;:,…])\s+|\s*\n\s*")


def split_clauses(text: str) -> list[str]:
    """Sentences and clauses of ``text``; pieces without a letter or digit join a neighbour.

    ``"3.5"`` and ``"1,000"`` stay whole: a break needs white space after the punctuation.
    """
    clauses: list[str] = []
    pending = ""  # leading pieces with nothing to speak
    for piece in _CLAUSE_BREAK.split(text):
        piece = piece.strip()
        if not piece:
            continue
        if not any(ch.isalnum() for ch in piece):
            if clauses:
                clauses[-1] += " " + piece
            else:
                pending += piece + " "
            continue
        clauses.append(pending + piece)
        pending = ""
    if pending:
        clauses.append(pending.strip())
    return clauses


def stream_channels(model: ControlModel, language: str, fps: float) -> tuple[str, ...]:
    """The channels of ``model``'s post-processed tracks (those a stream's frames carry)."""
    probe = PhoneSequence([Phone(SILENCE, 0.0, 1.0 / fps)], language)
    return animate(probe, model, fps).channels


def speech_messages(
    text: str,
    language: str,
    model: ControlModel,
    *,
    fps: float = DEFAULT_FPS,
    rate: float = 1.0,
    chunk_seconds: float = 0.1,
) -> Iterator[list[dict]]:
    """The ``/api/stream`` messages for ``text``, one list per clause, computed as they are asked for.

    The first list begins with ``start`` (``fps``, ``channels``, ``sample_rate``, ``model``);
    then come ``frames`` (``start_frame``, ``frames``) and ``audio`` (``seq``, ``start`` in
    seconds, ``pcm16`` base64 little-endian mono) in time order; the last list is ``[end]``
    (``n_frames``, ``duration`` in seconds). The frames cover the audio as
    :func:`vispeech.pipeline.speak` would: ``ceil(duration · fps)`` of them.
    """
    from vispeech.frontends.espeak import synthesize

    clauses = split_clauses(text)
    if not clauses:
        raise VispeechError("text is empty")
    channels = stream_channels(model, language, fps)
    samples_done = frames_done = seq = 0
    sample_rate = None
    for clause in clauses:
        speech = synthesize(clause, language, rate)
        track = animate(speech.phones, model, fps).select(channels)
        messages: list[dict] = []
        if sample_rate is None:
            sample_rate = speech.sample_rate
            messages.append({"type": "start", "fps": fps, "channels": list(channels),
                             "sample_rate": sample_rate, "model": model.name})
        pcm = np.clip(speech.audio * 32767.0, -32768, 32767).astype("<i2")
        clause_start = samples_done / sample_rate
        frame_end = _frames_before((samples_done + len(pcm)) / sample_rate, fps)
        values = _sample_rows(track.values, np.arange(frames_done, frame_end) - clause_start * fps)
        step = max(1, round(chunk_seconds * sample_rate))
        sent = frames_done
        for a in range(0, len(pcm), step):
            b = min(a + step, len(pcm))
            upto = frame_end if b == len(pcm) else min(frame_end, _frames_before((samples_done + b) / sample_rate, fps))
            if upto > sent:
                rows = np.round(values[sent - frames_done:upto - frames_done], 6).tolist()
                messages.append({"type": "frames", "start_frame": sent, "frames": rows})
                sent = upto
            messages.append({"type": "audio", "seq": seq, "start": (samples_done + a) / sample_rate,
                             "pcm16": base64.b64encode(pcm[a:b].tobytes()).decode("ascii")})
            seq += 1
        samples_done += len(pcm)
        frames_done = frame_end
        yield messages
    yield [{"type": "end", "n_frames": frames_done, "duration": samples_done / sample_rate}]


def _frames_before(seconds: float, fps: float) -> int:
    """Frames whose time ``k / fps`` lies before ``seconds`` (none at 0)."""
    return n_frames_for(seconds, fps) if seconds > 0 else 0


def _sample_rows(values: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Rows of ``values`` at fractional row ``positions`` (linear, clamped to the ends)."""
    positions = np.clip(positions, 0.0, len(values) - 1)
    lo = np.floor(positions).astype(int)
    hi = np.minimum(lo + 1, len(values) - 1)
    weight = (positions - lo)[:, None]
    return values[lo] * (1.0 - weight) + values[hi] * weight


class PhoneStream(ABC):
    """Frames for a stream of timed phones; see :func:`open_phone_stream`.

    :meth:`push` takes the next phones (in time order, none overlapping the ones before) and
    returns ``(start_frame, frames)``: the frames (rows over :attr:`channels`, at :attr:`fps`)
    that became computable, possibly none; :meth:`finish` returns the rest.
    """

    fps: float
    channels: tuple[str, ...]
    lookahead: int
    """Frames of phones after frame t that must be known before frame t is given."""

    def __init__(self, language: str) -> None:
        self.language = language
        self.end = 0.0
        """Latest phone end so far, seconds."""
        self.emitted = 0
        """Frames given so far."""
        self.closed = False

    @abstractmethod
    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        """Add phones; the frames that became ready."""

    @abstractmethod
    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed, up to the last phone's end."""

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self.closed = True

    def _checked(self, phones: Iterable[Phone]) -> list[Phone]:
        """The phones in the inventory's symbols; raises :class:`VispeechError` on bad timing."""
        if self.closed:
            raise VispeechError("this phone stream has ended")
        out = []
        end = self.end
        for p in phones:
            symbol, stress = parse_symbol(p.symbol, self.language)
            if not (math.isfinite(p.start) and math.isfinite(p.end)) or p.end <= p.start:
                raise VispeechError(f"phone {p.symbol!r} at {p.start} s must end after it starts")
            if p.start < end - 1e-6:
                raise VispeechError(
                    f"phone {p.symbol!r} starts at {p.start:.3f} s, before the previous one ends ({end:.3f} s)"
                )
            if p.end - end > MAX_PHONE_SECONDS:
                raise VispeechError(f"phone {p.symbol!r} ends more than {MAX_PHONE_SECONDS:g} s after the one before")
            out.append(Phone(symbol, float(p.start), float(p.end), None, p.stress or stress))
            end = p.end
        return out

    def _empty(self, start: int) -> tuple[int, np.ndarray]:
        return start, np.zeros((0, len(self.channels)))


class WindowPhoneStream(PhoneStream):
    """Frame t once phones cover frame ``t + lookahead``, from a re-prediction of a recent window.

    Each step animates (with post-processing) the phones from ``context`` seconds before the
    first frame not yet given up to the latest phone end, on a frame grid aligned with the
    stream's, and keeps the frames now ready.
    """

    def __init__(self, model: ControlModel, language: str, fps: float = DEFAULT_FPS,
                 lookahead: int = 2, context: float = 0.5) -> None:
        super().__init__(language)
        if lookahead < 0 or context < 0:
            raise VispeechError("lookahead and context must be >= 0")
        self.model = model
        self.fps = float(fps)
        self.lookahead = int(lookahead)
        self.context_frames = round(context * fps)
        self.channels = stream_channels(model, language, self.fps)
        self._recent: list[Phone] = []

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        new = self._checked(phones)
        if new:
            self._recent += new
            self.end = new[-1].end
        return self._emit(final=False)

    def finish(self) -> tuple[int, np.ndarray]:
        out = self._emit(final=True)
        self.close()
        return out

    def _emit(self, final: bool) -> tuple[int, np.ndarray]:
        known = _frames_before(self.end, self.fps)
        upto = known if final else known - self.lookahead
        if upto <= self.emitted or not self._recent:
            return self._empty(self.emitted)
        first_time = max(0, self.emitted - self.context_frames) / self.fps
        window = [p for p in self._recent if p.end > first_time] or self._recent[-1:]
        shift = math.floor(window[0].start * self.fps + 1e-9)  # whole frames, so the grids agree
        seconds = shift / self.fps
        local = PhoneSequence([replace(p, start=p.start - seconds, end=p.end - seconds) for p in window],
                              self.language).with_gaps_filled()
        values = animate(local, self.model, self.fps).select(self.channels).values
        rows = values[np.clip(np.arange(self.emitted, upto) - shift, 0, len(values) - 1)]
        start, self.emitted = self.emitted, upto
        keep_after = max(0, self.emitted - self.context_frames) / self.fps
        self._recent = [p for p in self._recent if p.end > keep_after] or self._recent[-1:]
        return start, rows


_WANT, _DONE = object(), object()


class ModelPhoneStream(PhoneStream):
    """A model's own ``predict_stream`` driven phone by phone (at the model's frame rate).

    ``predict_stream`` pulls phones from an iterator; here it runs in a helper thread that
    pulls from a queue, and :meth:`push` hands it phones one at a time, collecting what it
    yields until it asks for the next one.
    """

    def __init__(self, model: ControlModel, language: str) -> None:
        super().__init__(language)
        self.model = model
        self.fps = float(model.fps)
        self.channels = tuple(model.channels)
        self.lookahead = int(model.get_params().get("look_ahead", 0))
        self._inputs: queue.Queue = queue.Queue()
        self._outputs: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="vispeech-phone-stream", daemon=True)
        self._thread.start()
        self._collect(_WANT)

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        rows: list[np.ndarray] = []
        for phone in self._checked(phones):
            self._inputs.put(phone)
            self.end = phone.end
            rows += self._collect(_WANT)
        return self._result(rows)

    def finish(self) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this phone stream has ended")
        self.closed = True
        self._inputs.put(_DONE)
        return self._result(self._collect(_DONE))

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._inputs.put(_DONE)

    def _run(self) -> None:
        def phones() -> Iterator[Phone]:
            while True:
                self._outputs.put(_WANT)
                item = self._inputs.get()
                if item is _DONE:
                    return
                yield item

        try:
            for index, values in self.model.predict_stream(phones(), self.language):
                self._outputs.put((index, values))
            self._outputs.put(_DONE)
        except Exception as exc:  # handed to the caller of push/finish
            self._outputs.put(exc)

    def _collect(self, until: object) -> list[np.ndarray]:
        rows = []
        while True:
            item = self._outputs.get()
            if item is until:
                return rows
            if item is _DONE:  # the model stopped early: nothing more will come
                self.closed = True
                return rows
            if isinstance(item, Exception):
                self.closed = True
                raise item if isinstance(item, VispeechError) else VispeechError(f"streaming prediction failed: {item}")
            rows.append(np.asarray(item[1], dtype=float))

    def _result(self, rows: Sequence[np.ndarray]) -> tuple[int, np.ndarray]:
        start = self.emitted
        self.emitted += len(rows)
        return (start, np.stack(rows)) if rows else self._empty(start)


def open_phone_stream(model: ControlModel, language: str, fps: float = DEFAULT_FPS,
                      lookahead: int = 2, context: float = 0.5) -> PhoneStream:
    """A :class:`ModelPhoneStream` for a trained model with ``predict_stream``, else a :class:`WindowPhoneStream`.

    ``fps``, ``lookahead`` (frames) and ``context`` (seconds) apply to the window stream
    only; a model's own streaming runs at its frame rate with its own look-ahead.
    """
    if hasattr(model, "predict_stream") and getattr(model, "is_trained", True):
        return ModelPhoneStream(model, language)
    return WindowPhoneStream(model, language, fps, lookahead, context)
