"""The streaming engine: a model's frames given as its inputs arrive.

:class:`ModelStream` is what :meth:`~vispeech.models.contract.Estimator.stream` returns;
:class:`WindowStream` streams any model by re-predicting a bounded recent window (the default);
:class:`ResampledFrames` and :func:`rate_ratio` carry a model's own frame rate over to a
stream's, for the families that stream frame by frame (:mod:`vispeech.models.networks.tdnn`,
:mod:`vispeech.models.networks.audio_stream`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Generic, Self, TypeVar

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, first_frame
from vispeech.errors import VispeechError
from vispeech.limits import check_fps
from vispeech.motion.track import interpolate_rows

if TYPE_CHECKING:
    from fractions import Fraction

    from vispeech.models.contract import Estimator

ChunkT = TypeVar("ChunkT")
"""What a stream's :meth:`~ModelStream.push` takes: phones (``Iterable[Phone]``), or audio samples
(an audio network's :class:`~vispeech.models.networks.audio_stream.AudioStream`)."""


class ModelStream(ABC, Generic[ChunkT]):
    """Frames for phones that arrive in time order (a recogniser's or a TTS engine's).

    :meth:`push` takes the next phones (none overlapping the ones before) and returns
    ``(start_frame, frames)``: the rows over :attr:`channels` at :attr:`fps` that became
    computable, possibly none; :meth:`finish` returns the rest, up to the last phone's end.
    Frame t is given once the phones cover frame ``t + lookahead``.
    """

    def __init__(self, model: Estimator, language: str, fps: float) -> None:
        self.model = model
        self.language = language
        self.fps = check_fps(fps)
        self.channels = tuple(model.channels)
        self.lookahead = model.lookahead
        self.end = 0.0
        """Latest phone end so far, seconds."""
        self.emitted = 0
        """Frames given so far."""
        self.closed = False

    _fed: tuple[int, np.ndarray] | None
    """What :meth:`feed` left for :meth:`collect` (unset before the first feed)."""

    @abstractmethod
    def push(self, phones: ChunkT) -> tuple[int, np.ndarray]:
        """Add phones; the frames that became ready."""

    @abstractmethod
    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed."""

    def feed(self, phones: ChunkT) -> None:
        """Add phones, their frames to be taken with :meth:`collect`: :meth:`push` in two halves,
        so that the model work of several streams can be done together in between
        (:meth:`advance_together`). By default the work is done here."""
        start, rows = self.push(phones)
        fed = getattr(self, "_fed", None)
        self._fed = (start, rows) if fed is None or not len(fed[1]) else (fed[0], np.concatenate([fed[1], rows]))

    def collect(self) -> tuple[int, np.ndarray]:
        """The frames that became ready since the last :meth:`feed`."""
        fed, self._fed = getattr(self, "_fed", None), None
        return fed if fed is not None else self._empty()

    @classmethod
    def advance_together(cls, streams: Sequence[Self]) -> None:
        """Do the model work that :meth:`feed` left in ``streams`` (all of this class), sharing
        model calls where the class can; by default there is none left."""

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self.closed = True

    def _empty(self) -> tuple[int, np.ndarray]:
        return self.emitted, np.zeros((0, len(self.channels)))


def pushed_phones(phones: Iterable[Phone], language: str, previous_end: float | None) -> list[Phone]:
    """The phones pushed to a stream, checked (:meth:`~vispeech.alignment.phones.PhoneSequence.validate`,
    and none starting before ``previous_end``, the end of the phones pushed before), without their
    word indices: a stream keeps no words, and no model reads them."""
    new = [replace(p, word=None) for p in phones]
    if new:
        PhoneSequence(new, language).validate()
        first = new[0]
        if previous_end is not None and first.start < previous_end - TIME_TOLERANCE:
            raise VispeechError(f"phone {first.symbol} at {first.start:.3f} s starts before the previous one ends")
    return new


class WindowStream(ModelStream[Iterable[Phone]]):
    """Any model streamed by re-predicting a bounded recent window.

    Each step predicts the phones from ``context`` seconds before the first frame not yet
    given up to the latest phone end, on a frame grid aligned with the stream's, and keeps the
    frames now ready (those ``lookahead`` frames before the phones' end).
    """

    def __init__(self, model: Estimator, language: str, fps: float, context: float = 0.5) -> None:
        super().__init__(model, language, fps)
        self.context_frames = round(context * self.fps)
        self._recent: list[Phone] = []
        self._grid = 1  # windows start on multiples of this many stream frames, a whole number of model frames
        if model.frame_rate is not None:
            ratio = rate_ratio(model.frame_rate, self.fps)
            if ratio is not None:
                self._grid = ratio.denominator
            self.lookahead = math.ceil((model.lookahead + 1) * self.fps / model.frame_rate)

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this phone stream has ended")
        new = pushed_phones(phones, self.language, self._recent[-1].end if self._recent else None)
        if new:
            self._recent += new
            self.end = new[-1].end
        return self._emit(final=False)

    def finish(self) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this phone stream has ended")
        out = self._emit(final=True)
        self.close()
        return out

    def _emit(self, final: bool) -> tuple[int, np.ndarray]:
        known = first_frame(self.end, self.fps)  # frames before the phones' end
        upto = known if final else known - self.lookahead
        if upto <= self.emitted or not self._recent:
            return self._empty()
        first_time = max(0, self.emitted - self.context_frames) / self.fps
        window = [p for p in self._recent if p.end > first_time] or self._recent[-1:]
        shift = first_frame(window[0].start, self.fps, after=False)
        shift -= shift % self._grid  # whole stream (and model) frames, so the grids agree
        local = PhoneSequence(window, self.language).shifted(-shift / self.fps).with_gaps_filled()
        values = self.model.predict(local, self.fps).values
        rows = values[np.clip(np.arange(self.emitted, upto) - shift, 0, len(values) - 1)]
        start, self.emitted = self.emitted, upto
        keep_after = max(0, self.emitted - self.context_frames) / self.fps
        self._recent = [p for p in self._recent if p.end > keep_after] or self._recent[-1:]
        return start, rows


class ResampledFrames:
    """Model frames (at ``model_fps``) as they are computed, given out at a stream's ``fps``
    interpolated as :meth:`vispeech.motion.track.Track.resample` does, so a stream's frames equal
    the offline prediction's; model frames no later stream frame needs are dropped."""

    def __init__(self, model_fps: float, fps: float) -> None:
        self.model_fps, self.fps = float(model_fps), float(fps)
        self.first = 0
        """Model frame index of the oldest frame kept."""
        self._frames: list[np.ndarray] = []

    def add(self, row: np.ndarray) -> None:
        """Append the next model frame."""
        self._frames.append(row)

    @property
    def computed(self) -> int:
        """Model frames computed so far."""
        return self.first + len(self._frames)

    def ready(self) -> int:
        """Stream frames whose interpolation the computed model frames cover."""
        if not self.computed:
            return 0
        return first_frame((self.computed - 1) / self.model_fps, self.fps, after=False) + 1

    def give(self, emitted: int, upto: int) -> np.ndarray:
        """Stream frames ``emitted .. upto - 1`` (frames past the last model frame hold its values);
        needs at least one model frame."""
        positions = np.arange(emitted, upto) * (self.model_fps / self.fps) - self.first
        rows = interpolate_rows(np.stack(self._frames), positions)  # as Track.resample interpolates
        drop = min(max(0, int(np.floor(upto * self.model_fps / self.fps)) - 1 - self.first), len(self._frames) - 1)
        del self._frames[:drop]
        self.first += drop
        return rows


def rate_ratio(model_fps: float, fps: float) -> Fraction | None:
    """``model_fps / fps`` as a simple fraction (denominator at most 1000), or ``None`` when it is none:
    every ``denominator`` frames at ``fps`` are a whole number (``numerator``) of model frames."""
    from fractions import Fraction  # here: fractions imports decimal, and only streams need it

    ratio = Fraction(model_fps / fps).limit_denominator(1000)
    return ratio if abs(float(ratio) - model_fps / fps) < 1e-9 else None
