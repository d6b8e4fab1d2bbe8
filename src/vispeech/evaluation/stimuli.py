"""Stimuli for perceptual tests: speech degraded so that seeing the face matters.

Beskow (2004) measured how much a talking head helps by playing its speech through a
noise-excited vocoder (Shannon et al. 1995) with three bands between 100 and 5000 Hz: the
words' rhythm and rough spectrum stay, their fine structure (voice pitch, formant detail) goes,
and listeners then lean on the lips. :func:`noise_vocode` does that:

1. the speech is split into ``bands`` bands with edges spaced evenly on a log scale from
   ``low`` to ``high`` Hz (100, 368, 1357 and 5000 Hz for three), each a 4th-order
   Butterworth band-pass run forwards and backwards (no phase shift);
2. each band's envelope: half-wave rectified, low-passed at ``envelope_cutoff`` Hz
   (160 Hz, Shannon's widest, keeps the syllables and their onsets);
3. white noise (seeded) through the same band-pass, times the envelope, scaled to the band's
   own RMS;
4. the bands summed and scaled to the input's RMS (clipped to [-1, 1]).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from vispeech.errors import VispeechError


def band_edges(bands: int = 3, low: float = 100.0, high: float = 5000.0) -> np.ndarray:
    """The ``bands + 1`` band edges (Hz), evenly spaced on a log scale from ``low`` to ``high``."""
    return np.geomspace(low, high, bands + 1)


def noise_vocode(samples: np.ndarray, sample_rate: int, *, bands: int = 3, low: float = 100.0,
                 high: float = 5000.0, envelope_cutoff: float = 160.0, seed: int = 0) -> np.ndarray:
    """``samples`` (mono, float in [-1, 1]) through a noise-excited vocoder (see the module
    docstring); the same length, float32. Raises :class:`VispeechError` for bands beyond the
    Nyquist frequency or fewer than one band."""
    x = np.asarray(samples, dtype=np.float64)
    if bands < 1:
        raise VispeechError(f"a vocoder needs one band at least, got {bands}")
    if not 0 < low < high < sample_rate / 2:
        raise VispeechError(f"vocoder bands {low:g}-{high:g} Hz must lie below half the sample rate "
                            f"({sample_rate / 2:g} Hz)")
    if x.ndim != 1 or len(x) < 0.05 * sample_rate:
        raise VispeechError("the vocoder takes mono audio of 50 ms or more")
    rng = np.random.default_rng(seed)
    smooth = butter(4, envelope_cutoff, fs=sample_rate, output="sos")
    out = np.zeros_like(x)
    edges = band_edges(bands, low, high)
    for lo, hi in zip(edges[:-1], edges[1:]):
        band = butter(4, [lo, hi], btype="band", fs=sample_rate, output="sos")
        speech = sosfiltfilt(band, x)
        envelope = np.maximum(sosfiltfilt(smooth, np.maximum(speech, 0.0)), 0.0)
        carrier = sosfiltfilt(band, rng.standard_normal(len(x)))
        voiced = carrier * envelope
        gain = np.sqrt(np.mean(speech ** 2) / max(np.mean(voiced ** 2), 1e-20))
        out += voiced * gain
    level = np.sqrt(np.mean(x ** 2) / max(np.mean(out ** 2), 1e-20))
    return np.clip(out * level, -1.0, 1.0).astype(np.float32)
