"""Ease curves: the thesis's cubic Bézier ease as a function of time, and the smoothstep cubic.

The curve runs from (0, 0) to (a, 1) with control points (c1·a, 0) and (c2·a, 1):

    x(t) = 3·c1·a·(1−t)²·t + 3·c2·a·(1−t)·t² + a·t³
    y(t) = 3·(1−t)·t² + t³,            0 ≤ t ≤ 1

x is time (frames or seconds, the same unit as a) and y the blend strength. The consonant
fades and the baseline's vowel transitions use c1 = c2 = 0.5; the upper-lip overlay uses
c1 = 0.6, c2 = 0.75. For a given x the curve parameter t is found numerically
(safeguarded Newton iteration, vectorised), since x(t) has no handy inverse.
"""

from __future__ import annotations

import numpy as np

from vispeech.errors import VispeechError

_TOLERANCE = 1e-12
_MAX_ITERATIONS = 60


def bezier_ease(x, length, c1: float = 0.5, c2: float = 0.5) -> np.ndarray:
    """Strength y in [0, 1] at times ``x`` of an ease curve of duration ``length``.

    ``x`` and ``length`` broadcast against each other; y is 0 for x ≤ 0 and 1 for
    x ≥ length (a zero ``length`` is a step at 0). Requires 0 ≤ c1 ≤ c2 ≤ 1, which makes
    the curve non-decreasing.
    """
    if not 0.0 <= c1 <= c2 <= 1.0:
        raise VispeechError(f"Bézier control fractions need 0 <= c1 <= c2 <= 1, got {c1}, {c2}")
    x, length = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(length, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(length > 0, x / length, np.where(x >= 0, 1.0, 0.0))
    u = np.clip(u, 0.0, 1.0)
    t = _solve_symmetric(u) if c1 == c2 == 0.5 else _solve(u, c1, c2)
    return 3.0 * (1.0 - t) * t * t + t * t * t


def _solve_symmetric(u: np.ndarray) -> np.ndarray:
    """t with x(t)/a = u for c1 = c2 = 1/2, in closed form.

    Then x(t)/a = t³ − 1.5t² + 1.5t; with t = s + 1/2 this is the depressed cubic
    s³ + 0.75·s + (1/2 − u) = 0, whose one real root Cardano's formula gives.
    """
    half = 0.5 * (u - 0.5)
    root = np.sqrt(half * half + 1.0 / 64.0)
    return 0.5 + np.cbrt(half + root) + np.cbrt(half - root)


def _solve(u: np.ndarray, c1: float, c2: float) -> np.ndarray:
    """t in [0, 1] with x(t)/a = u, for a non-decreasing x(t)."""
    t = u.copy()
    lo, hi = np.zeros_like(u), np.ones_like(u)
    for _ in range(_MAX_ITERATIONS):
        s = 1.0 - t
        f = 3.0 * c1 * s * s * t + 3.0 * c2 * s * t * t + t * t * t - u
        done = np.abs(f) <= _TOLERANCE
        if done.all():
            break
        hi = np.where(f > 0, t, hi)
        lo = np.where(f > 0, lo, t)
        slope = 3.0 * (c1 * s * s + 2.0 * (c2 - c1) * s * t + (1.0 - c2) * t * t)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = t - f / slope
        inside = (slope > 0) & (newton > lo) & (newton < hi)
        t = np.where(done, t, np.where(inside, newton, 0.5 * (lo + hi)))
    return t


def smoothstep(x, edges: tuple[float, float] = (0.0, 1.0)) -> np.ndarray:
    """3s² − 2s³ of ``s = (x − edges[0]) / (edges[1] − edges[0])`` clipped to [0, 1]: 0 at and below
    the first edge, 1 at and above the second, with zero slope at both."""
    s = np.clip((np.asarray(x, dtype=float) - edges[0]) / (edges[1] - edges[0]), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)
