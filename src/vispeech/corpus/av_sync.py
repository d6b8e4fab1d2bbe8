"""Audio–video sync of a captured take, and optional smoothing of tracker jitter.

A camera's sound can lead or trail its picture (a phone's or a webcam's capture pipeline, a
re-encoded file). :func:`openness_offset` measures it from the take itself: at 100 Hz, the
rate of change of the inner-lip gap (:func:`vispeech.corpus.articulation.lip_gap`) is
cross-correlated with that of the jaw opening a speech model hears in the sound
(:func:`vispeech.pipeline.speech_openness`) over lags of up to ``max_lag``; the peak, refined
by a parabola, is the offset. Positive: the picture is late (the mouth moves after the sound).
It needs :data:`MIN_OPENNESS_SECONDS` of the take (on 3-s takes of grid_s1's test split 1 % of
the estimates were more than 40 ms off, none more than 80 ms; docs/capture.md).
:func:`estimate_offset` does the same with the sound's log energy (low-passed at 10 Hz) in place
of the model, less what synchronous recordings show (:data:`NATURAL_LAG`, measured on grid_s1),
for a caller without a model: it needs :data:`MIN_SECONDS` (on 3-s takes a fifth of its
estimates are wrong by more than 80 ms, on 30 s of speech none of 30 were).
:func:`utterance_offset` measures a recorded utterance so (its lip landmarks against its audio;
``vispeech corpus info --sync``). :func:`shift_frames` moves a track by an offset (linear
interpolation, ends held).

:func:`smooth_frames` is a Savitzky–Golay filter (scipy) over the frames, off unless asked:
on grid_s1 it cuts jawOpen's frame-to-frame jitter (mean absolute second difference) by 29 %
(median of 50 tracks) and keeps its movements (r ≥ 0.99 with the raw track).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from vispeech.frontends.audio import AudioClip
    from vispeech.utterance import Utterance

ANALYSIS_RATE = 100
"""Hz at which the lip gap and the sound (its energy, or the jaw a speech model hears in it) are compared."""
MIN_SECONDS = 10.0
"""The shortest take whose offset :func:`estimate_offset` tells (NaN below)."""
MIN_OPENNESS_SECONDS = 3.0
"""The shortest take whose offset :func:`openness_offset` tells (NaN below)."""
NATURAL_LAG = 0.025
"""Seconds by which the lip gap's changes seem to follow the sound's in a synchronous recording
(frame times taken at their middles): the median over 30 stretches of 30 s of grid_s1 (its first
300 utterances joined ten at a time; all 30 within -3 and 63 ms)."""
SMOOTHING_WINDOW = 0.2
"""Seconds of the Savitzky–Golay window (5 frames at 25 fps), polynomial order 2."""


def estimate_offset(
    gap: np.ndarray,
    fps: float,
    samples: np.ndarray,
    sample_rate: int,
    mask: np.ndarray | None = None,
    max_lag: float = 0.3,
) -> float:
    """Seconds by which the picture is late against the sound (see the module docstring), from a
    take's per-frame lip ``gap`` at ``fps`` and its sound; ``mask`` marks the frames with a face
    (the others do not count). NaN for a take shorter than :data:`MIN_SECONDS` or one whose
    mouth or sound does not change."""
    from scipy.signal import butter, sosfiltfilt  # scipy: in the `capture` extra

    n = len(gap)
    if n / fps < MIN_SECONDS:
        return float("nan")
    m = int(n / fps * ANALYSIS_RATE)
    edges = np.clip(np.round(np.arange(m + 1) * sample_rate / ANALYSIS_RATE).astype(int), 0, len(samples))
    squares = np.concatenate([[0.0], np.cumsum(np.asarray(samples, dtype=float) ** 2)])
    rms = np.sqrt((squares[edges[1:]] - squares[edges[:-1]]) / np.maximum(np.diff(edges), 1))
    energy = sosfiltfilt(butter(2, 10, fs=ANALYSIS_RATE, output="sos"), np.log(rms + 1e-6))
    return _lag(gap, fps, 0.5, energy, mask, max_lag) - NATURAL_LAG


def openness_offset(
    gap: np.ndarray, fps: float, openness: np.ndarray, mask: np.ndarray | None = None, max_lag: float = 0.3
) -> float:
    """Seconds by which the picture is late against the sound, as :func:`estimate_offset` says,
    from the jaw opening a speech model hears in the sound instead of its energy
    (:func:`vispeech.pipeline.speech_openness`: ``openness`` at :data:`ANALYSIS_RATE` from the
    sound's start, frame k of the picture at ``k / fps``). NaN for a take shorter than
    :data:`MIN_OPENNESS_SECONDS` or one whose mouth or model does not move."""
    n = len(gap)
    if n / fps < MIN_OPENNESS_SECONDS:
        return float("nan")
    return _lag(gap, fps, 0.0, np.asarray(openness, dtype=float)[: int(n / fps * ANALYSIS_RATE)], mask, max_lag)


def utterance_offset(utterance: Utterance, openness: Callable[[AudioClip], np.ndarray]) -> float:
    """Seconds by which a recorded ``utterance``'s picture is late against its sound:
    :func:`openness_offset` of its tracked inner-lip gap (its ``lm13``/``lm14``/``lm33``/``lm263``
    landmarks; untracked frames left out) and ``openness`` of its audio (e.g.
    :func:`vispeech.pipeline.speech_openness`). NaN without those landmarks or a track, or for
    an utterance shorter than :data:`MIN_OPENNESS_SECONDS`."""
    from vispeech.corpus.articulation import lip_gap
    from vispeech.errors import VispeechError
    from vispeech.frontends.audio import AudioClip

    track = utterance.track
    if track is None or utterance.landmarks is None or track.n_frames / track.fps < MIN_OPENNESS_SECONDS:
        return float("nan")
    try:
        gap = lip_gap(utterance.landmarks)
    except VispeechError:  # no lip or eye-corner landmarks
        return float("nan")
    samples, rate = utterance.load_audio()
    sound = openness(AudioClip.from_array(samples, rate))
    return openness_offset(gap, track.fps, sound, utterance.frame_mask) + track.start_time


def _lag(
    gap: np.ndarray, fps: float, middle: float, sound: np.ndarray, mask: np.ndarray | None, max_lag: float
) -> float:
    """Seconds by which the rate of change of ``gap`` (frame k at ``(k + middle) / fps``) follows
    that of ``sound`` (a curve at :data:`ANALYSIS_RATE`) where they agree best, within
    ``max_lag``, refined by a parabola; NaN where either does not change."""
    gap = np.asarray(gap, dtype=float)
    known = np.isfinite(gap) if mask is None else (np.asarray(mask, bool) & np.isfinite(gap))
    n, m = len(gap), len(sound)
    if known.sum() < 2 or m < 3:
        return float("nan")
    times = np.arange(m) / ANALYSIS_RATE
    frames = np.flatnonzero(known)
    g = np.gradient(np.interp(times, (frames + middle) / fps, gap[frames]))
    e = np.gradient(sound)
    use = known[np.minimum((times * fps).astype(int), n - 1)]
    if np.std(g[use]) == 0 or np.std(e[use]) == 0:
        return float("nan")
    g = np.where(use, (g - g[use].mean()) / g[use].std(), 0.0)
    e = np.where(use, (e - e[use].mean()) / e[use].std(), 0.0)
    reach = int(round(max_lag * ANALYSIS_RATE))
    lags = np.arange(-reach, reach + 1)
    scores = np.array(
        [np.mean(g[max(0, -lag) : m - max(0, lag)] * e[max(0, lag) : m - max(0, -lag)]) for lag in lags.tolist()]
    )
    k = int(np.argmax(scores))
    shift = 0.0
    if 0 < k < len(lags) - 1:
        curve = scores[k - 1] - 2 * scores[k] + scores[k + 1]
        shift = 0.5 * (scores[k - 1] - scores[k + 1]) / curve if curve < 0 else 0.0
    return float(-(lags[k] + shift) / ANALYSIS_RATE)


def shift_frames(values: np.ndarray, offset: float, fps: float) -> np.ndarray:
    """``values`` (frames × channels) moved ``offset`` seconds earlier (a late picture put back in
    time with the sound): frame k takes the values at ``k + offset · fps``, interpolated linearly,
    the first and last frames held beyond the ends; NaN rows stay NaN where they land."""
    values = np.asarray(values, dtype=float)
    frames = np.arange(len(values))
    source = frames + offset * fps
    out = np.empty_like(values)
    found = np.isfinite(values).all(axis=1)
    for j in range(values.shape[1]):
        out[:, j] = np.interp(source, frames[found], values[found, j])
    nearest = np.clip(np.round(source).astype(int), 0, len(values) - 1)
    out[~found[nearest]] = np.nan
    return out


def smooth_frames(values: np.ndarray, fps: float) -> np.ndarray:
    """``values`` (frames × channels) through a Savitzky–Golay filter of :data:`SMOOTHING_WINDOW`
    seconds (at least 5 frames, odd), order 2, over each run of frames with a face; NaN rows stay."""
    from scipy.signal import savgol_filter  # scipy: in the `capture` extra

    values = np.asarray(values, dtype=float)
    window = max(5, int(round(SMOOTHING_WINDOW * fps)) | 1)
    out = values.copy()
    found = np.isfinite(values).all(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], found.astype(int), [0]])))
    for start, end in zip(edges[::2], edges[1::2]):
        if end - start >= window:
            out[start:end] = savgol_filter(values[start:end], window, 2, axis=0)
    return out
