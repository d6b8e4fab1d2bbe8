"""Beskow's (1995) rule-based model: under-specified targets, interpolation, smoothing.

Each phone aims at its target vector, whose undefined entries (see
:class:`vispeech.targets.tables.TargetTable`) take no part: every channel is linearly
interpolated between the target points of the phones that define it, so lip rounding, for
instance, runs straight from one vowel to the next across a consonant cluster. A phone's
target points sit at its centre ± ``hold``/2 of its duration (one point at the centre when
``hold`` is 0). The trajectory is then smoothed by a Gaussian filter of standard deviation
``sigma`` seconds (edges held).
"""

from __future__ import annotations

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.rules.phone_targets import PhoneTargetModel, family_defaults
from vispeech.motion.track import Track

MAX_SIGMA = 1.0
"""Seconds: the widest smoothing (a Gaussian's standard deviation); wider smooths whole words away
(and its kernel would run to millions of frames: ``sigma=1e9`` asked for terabytes)."""


class BeskowRules(PhoneTargetModel):
    """Interpolated under-specified targets. Parameters: ``hold`` (fraction of a phone held
    at its target, 0..1), ``sigma`` (smoothing in seconds, 0 to :data:`MAX_SIGMA`), ``targets``."""

    family = "beskow-rules"
    defaults = family_defaults("beskow-rules")

    def _check_params(self) -> None:
        super()._check_params()
        hold, sigma = self._params["hold"], self._params["sigma"]
        if not isinstance(hold, (int, float)) or not 0.0 <= hold <= 1.0:
            raise VispeechError(f"beskow-rules hold must lie in [0, 1], got {hold!r}")
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not 0.0 <= sigma <= MAX_SIGMA:
            raise VispeechError(f"beskow-rules sigma must be seconds from 0 to {MAX_SIGMA:g}, got {sigma!r}")

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        half = 0.5 * self._params["hold"] * seg.durations
        points = np.stack([seg.centres - half, seg.centres + half], axis=1).ravel()
        targets = np.repeat(seg.targets, 2, axis=0)
        defined = np.repeat(seg.defined, 2, axis=0)
        out = np.empty((len(seg.times), len(self.channels)))
        for ch in range(len(self.channels)):
            use = defined[:, ch] if defined[:, ch].any() else slice(None)
            out[:, ch] = np.interp(seg.times, points[use], targets[use, ch])
        sigma_frames = self._params["sigma"] * fps
        if sigma_frames > 0:
            out = gaussian_smooth(out, sigma_frames)
        return self._track(out, fps)


def gaussian_smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """``(frames, channels)`` float64 values smoothed over frames by a Gaussian of ``sigma`` > 0
    frames, cut at 4 ``sigma``, the edge frames held beyond the ends: the numbers of
    ``scipy.ndimage.gaussian_filter1d(values, sigma, axis=0, mode="nearest")``, whose kernel
    and order of summation (the centre, then symmetric pairs from the outside in) it follows."""
    radius = int(4.0 * sigma + 0.5)
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 / (sigma * sigma) * offsets**2)
    kernel = kernel / kernel.sum()
    padded = np.pad(values, ((radius, radius), (0, 0)), mode="edge")
    n = len(values)
    out = padded[radius : radius + n] * kernel[radius]
    for j in range(radius, 0, -1):
        out += (padded[radius - j : radius - j + n] + padded[radius + j : radius + j + n]) * kernel[radius - j]
    return out
