"""Where the speech in a clip is: frame energy against the clip's loudest frame and its noise floor.

Energy is the power of each 10 ms frame (the framing of :mod:`vispeech.frontends.features`) in
the band :data:`BAND_HZ`, which leaves out rumble and hum, in dB relative to a full-scale
square wave. A frame is speech when it lies within :data:`BELOW_PEAK_DB` of the loudest frame
and at least :data:`ABOVE_FLOOR_DB` above the noise floor (the 10th percentile of the frames
that are not digital silence), so a recording with a second of silence or steady noise before
the first word starts where the word does.
"""

from __future__ import annotations

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.features import FRAME_RATE, N_FFT, SAMPLE_RATE, WINDOW, power_spectrogram

BAND_HZ = (250.0, 8000.0)
"""The band whose energy counts, in Hz."""
BELOW_PEAK_DB = 40.0
"""Speech frames lie at most this far below the loudest frame."""
ABOVE_FLOOR_DB = 6.0
"""Speech frames lie at least this far above the noise floor."""
SILENT_DB = -70.0
"""A clip whose loudest frame is below this level (dB re full scale) is silent."""
DIGITAL_SILENCE_DB = -100.0
"""Frames at or below this level are digital silence and do not count in the noise floor."""


def band_energy(clip: AudioClip) -> np.ndarray:
    """Per-frame power in :data:`BAND_HZ`, dB relative to a full-scale square wave, at ``FRAME_RATE``."""
    power = power_spectrogram(clip.resampled(SAMPLE_RATE).samples)
    freqs = np.linspace(0.0, SAMPLE_RATE / 2, power.shape[1])
    band = (freqs >= BAND_HZ[0]) & (freqs <= BAND_HZ[1])
    window = np.hanning(WINDOW + 1)[:-1]  # the periodic Hann window the spectrogram uses
    mean_square = 2.0 * power[:, band].sum(axis=1) / (N_FFT * np.sum(window**2))  # Parseval, one-sided
    return 10.0 * np.log10(np.maximum(mean_square, 1e-15))


def speech_span(clip: AudioClip) -> tuple[float, float]:
    """Start and end in seconds of the speech in ``clip``: the centres of its first and last
    speech frames. Raises :class:`VispeechError` when no frame is speech (silence, steady noise)."""
    energy = band_energy(clip)
    peak = float(energy.max())
    if peak < SILENT_DB:
        raise VispeechError(f"the audio is silent (its loudest 10 ms is {peak:.0f} dB below full scale)")
    floor = float(np.percentile(energy[energy > DIGITAL_SILENCE_DB], 10))
    speech = np.flatnonzero(energy > max(peak - BELOW_PEAK_DB, floor + ABOVE_FLOOR_DB))
    if speech.size == 0:
        raise VispeechError(f"the audio has no speech: nothing stands {ABOVE_FLOOR_DB:g} dB above its noise floor")
    return speech[0] / FRAME_RATE, min(speech[-1] / FRAME_RATE, clip.duration)
