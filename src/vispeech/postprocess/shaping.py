"""Curve shaping: the thesis's jawOpen range shift and soft ceilings, and peak confinement."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vispeech.errors import VispeechError

PEAK_SLOPE = 1e-4
"""Smallest per-frame slope :func:`confine_peaks` leaves in lowered stretches (no flat tops)."""


def shift_range(curve: np.ndarray, amount: float) -> np.ndarray:
    """The thesis's jawOpen shift: ``w − (w_max − w)/(w_max − w_min) · amount``.

    Maxima stay where they are and minima drop by ``amount``, which helps the lips close. A
    constant curve is returned unchanged.
    """
    curve = np.asarray(curve, dtype=float)
    low, high = curve.min(), curve.max()
    if high - low <= 1e-12:
        return curve.copy()
    return curve - (high - curve) / (high - low) * amount


@dataclass(frozen=True)
class SoftCeiling:
    """The thesis's soft maximum: values above ``threshold`` are squeezed linearly so that
    ``input_max`` maps to ``maximum``:

        w' = threshold + (maximum − threshold)/(input_max − threshold) · (w − threshold)   if w > threshold

    The thesis states these relative to the ground truth's global maximum (see
    :meth:`relative`); at run time there is no ground truth, so they are absolute values.
    """

    threshold: float
    maximum: float
    input_max: float = 1.0

    def __post_init__(self) -> None:
        if not self.threshold < self.maximum <= self.input_max:
            raise VispeechError(
                "soft ceiling needs threshold < maximum <= input_max, "
                f"got {self.threshold}, {self.maximum}, {self.input_max}"
            )

    @classmethod
    def relative(cls, a: float, b: float, reference_max: float) -> SoftCeiling:
        """The thesis's form: ``maximum = a · reference_max``, ``threshold = b · maximum``."""
        maximum = a * reference_max
        return cls(threshold=b * maximum, maximum=maximum, input_max=reference_max)

    def __call__(self, curve: np.ndarray) -> np.ndarray:
        curve = np.asarray(curve, dtype=float)
        gain = (self.maximum - self.threshold) / (self.input_max - self.threshold)
        return np.where(curve > self.threshold, self.threshold + gain * (curve - self.threshold), curve)


def confine_peaks(curve: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Lower ``curve`` outside the ``allowed`` frames until none of its local maxima lies there.

    Each run of disallowed frames becomes the largest curve below the original that falls
    from its left neighbour and rises to its right neighbour, each by at least
    :data:`PEAK_SLOPE` per frame (so no flat top hides a peak). Allowed frames are untouched.
    All runs are done at once: the running minima restart at each run because every run is
    lifted above the ones after it (by ``lift``) before the minimum runs over them.
    """
    curve = np.asarray(curve, dtype=float)
    out = curve.copy()
    n = len(curve)
    edges = np.diff(np.concatenate(([0], (~np.asarray(allowed, dtype=bool)).astype(np.int8), [0])))
    first, stop = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if not len(first):
        return out
    lo, hi = np.maximum(first - 1, 0), np.minimum(stop + 1, n)  # each run with its allowed neighbours
    length = hi - lo
    run = np.repeat(np.arange(len(first)), length)
    k = np.arange(length.sum()) - np.repeat(np.cumsum(length) - length, length)  # frame within the run
    x = curve[lo[run] + k]
    slope = k * PEAK_SLOPE
    lift = 4.0 + 2.0 * PEAK_SLOPE * n  # more than any x ± slope can differ within the whole curve
    falls = np.minimum.accumulate(x + slope - lift * run) + lift * run - slope  # falls from the left
    rises = (np.minimum.accumulate((x - slope + lift * run)[::-1]))[::-1] - lift * run + slope  # rises to the right
    from_left = ((first > 0) | (stop == n))[run]
    from_right = ((stop < n) | (first == 0))[run]
    best = np.maximum(np.where(from_left, falls, -np.inf), np.where(from_right, rises, -np.inf))
    inner = (k >= (first - lo)[run]) & (k < (stop - lo)[run])
    frames = (lo[run] + k)[inner]
    out[frames] = np.minimum(best[inner], curve[frames])
    return out
