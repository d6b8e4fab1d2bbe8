"""The mouth at rest in silence: far from speech the jaw, lip and tongue channels ease to 0.

0 on every channel of :data:`~vispeech.motion.arkit.MOUTH_CHANNELS` and
:data:`~vispeech.motion.arkit.TONGUE_CHANNELS` is the rig's neutral pose: jaw closed, lips
together, the tongue lying low (ARKit rigs are modelled so). Within :data:`HOLD` seconds of
speech a model's own motion is kept: the opening that anticipates a sound (and a breath in, where
the audio's loudness shows one: it counts as speech) and the closing after it; beyond that the
channels fade to rest over :data:`EASE` seconds (smoothstep). The rule looks only at the nearest
speech on either side of a frame, so leading and trailing silence reach rest when they last
``HOLD + EASE``, a pause within an utterance when it lasts twice that, and a window of frames
post-processed on its own (a stream's) gets what the whole utterance would, given that much
context on both sides. :func:`rest_ease` takes a face to rest from any frame (a stream cut short),
and a stream's :class:`SentFrames` keeps the frames it gave to ease from the one a client shows.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.motion.arkit import MOUTH_CHANNELS, TONGUE_CHANNELS
from vispeech.motion.easing import smoothstep
from vispeech.motion.track import Track

HOLD = 0.1
"""Seconds before and after speech in which the model's frames are kept as they are (the margin
around speech that evaluation scores, :data:`vispeech.evaluation.metrics.SPEECH_MARGIN`, too)."""
EASE = 0.1
"""Seconds over which the mouth eases from the model's frames to rest, beyond the hold."""
REST_CHANNELS: tuple[str, ...] = MOUTH_CHANNELS + TONGUE_CHANNELS[1:]
"""The channels brought to rest: jaw, lips, cheek puff and the tongue."""
_RESTING = frozenset(REST_CHANNELS)


def speech_intervals(speech: PhoneSequence | Iterable[tuple[float, float]]) -> np.ndarray:
    """Where speech is: ``(n, 2)`` start and end seconds, sorted and merged, of the phones that are
    not silence, or of spans (start, end seconds: speech found in audio by its loudness)."""
    if isinstance(speech, PhoneSequence):
        pieces = [(p.start, p.end) for p in speech if not p.is_silence]
    else:
        pieces = [(float(start), float(end)) for start, end in speech]
    merged: list[list[float]] = []
    for start, end in sorted(pieces):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return np.array(merged, dtype=float).reshape(-1, 2)


def rest_weights(times: np.ndarray, speech: np.ndarray) -> np.ndarray:
    """Per time in ``times`` (seconds), how far the mouth is at rest: 0 within speech and the hold
    around it, 1 beyond it and the ease; ``speech`` as :func:`speech_intervals` gives it (none:
    all at rest)."""
    times = np.asarray(times, dtype=float)
    if not len(speech):
        return np.ones_like(times)
    starts, ends = speech[:, 0], speech[:, 1]
    following = np.searchsorted(starts, times, side="left")  # the first speech starting at or after t
    preceding = np.searchsorted(ends, times, side="right") - 1  # the last speech ending at or before t
    to_next = np.where(following < len(starts), starts[np.minimum(following, len(starts) - 1)] - times, np.inf)
    from_last = np.where(preceding >= 0, times - ends[np.maximum(preceding, 0)], np.inf)
    away = np.minimum(to_next, from_last) - HOLD
    within = np.searchsorted(starts, times, side="right") - 1
    inside = (within >= 0) & (times <= ends[np.maximum(within, 0)])
    return np.where(inside, 0.0, smoothstep(away, (0.0, EASE)))


def rest_in_silence(track: Track, speech: np.ndarray) -> Track:
    """A copy of ``track`` with :data:`REST_CHANNELS` eased to 0 away from ``speech`` (see
    :func:`rest_weights`; frame k at ``track.start_time + k / fps``)."""
    out = track.copy()
    keep = 1.0 - rest_weights(track.start_time + np.arange(track.n_frames) / track.fps, speech)
    columns = [i for i, channel in enumerate(out.channels) if channel in _RESTING]
    out.values[:, columns] *= keep[:, None]
    return out


def rest_ease(last: np.ndarray, fps: float) -> np.ndarray:
    """The frames after a frame ``last`` (a row over a stream's channels) that take the face to
    rest, every channel at 0, over :data:`EASE` seconds (smoothstep):
    ``ceil(EASE · fps)`` rows, the last at rest."""
    n = max(1, math.ceil(EASE * fps - 1e-9))
    keep = 1.0 - smoothstep(np.arange(1, n + 1) / n)
    return keep[:, None] * np.asarray(last, dtype=float)[None, :]


CANCEL_SECONDS = 120.0
"""How far back (seconds of frames) a cancel may name the frame a client shows."""


class SentFrames:
    """The latest frames a stream gave (:data:`CANCEL_SECONDS` of them), so that a cancel eases
    the face to rest from the one a client shows when the listener interrupts."""

    def __init__(self, n_channels: int, fps: float) -> None:
        self.n_channels = n_channels
        self.fps = fps
        self.count = 0
        """Frames given so far."""
        self._chunks: list[np.ndarray] = []
        self._first = 0  # the number of the first frame kept

    def add(self, rows: np.ndarray) -> None:
        """The next frames given."""
        if not len(rows):
            return
        self._chunks.append(np.asarray(rows, dtype=np.float32))
        self.count += len(rows)
        while self.count - self._first - len(self._chunks[0]) >= CANCEL_SECONDS * self.fps:
            self._first += len(self._chunks.pop(0))

    def ease(self, frame: int | None = None) -> tuple[int, np.ndarray]:
        """``(k + 1, rows)``: the frames after frame ``k`` that take the face from it to rest
        (:func:`rest_ease`), ``k`` being ``frame`` (the last given if
        ``None`` or later, the oldest kept if earlier), to be shown in place of the frames given
        after it."""
        if not self.count:
            return 0, rest_ease(np.zeros(self.n_channels), self.fps)
        k = self.count - 1 if frame is None else min(max(frame, self._first), self.count - 1)
        kept = np.concatenate(self._chunks)
        return k + 1, rest_ease(kept[k - self._first], self.fps)
