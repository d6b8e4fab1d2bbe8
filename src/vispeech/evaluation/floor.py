"""A floor for audio models: the loudness of the speech taken as jawOpen.

The jaw opens most on loud vowels, so the level of the sound alone already follows it a
little. :class:`LoudnessFloor` animates nothing but that: a model that scores no better has
learned nothing of articulation. It is an audio estimator that :func:`~vispeech.evaluation.report.evaluate_models`
scores like any model; it is not registered, as nobody should animate a face with it.
"""

from __future__ import annotations

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.models.contract import Estimator
from vispeech.models.fitting import FitRun
from vispeech.motion.track import Track

SILENT_DB = -60.0
"""Level (dB re full scale) at and below which the floor's jaw is shut; 0 dB opens it fully."""


def loudness_envelope(clip: AudioClip, fps: float) -> np.ndarray:
    """The RMS level of ``clip`` per frame at ``fps``, in dB re full scale (at least
    :data:`SILENT_DB`): ``clip.n_frames(fps)`` values, frame k over the samples within half a
    frame of k / fps seconds."""
    samples = clip.samples.astype(np.float64)
    energy = np.concatenate([[0.0], np.cumsum(samples**2)])
    centres = np.arange(clip.n_frames(fps)) / fps
    first, last = (
        np.clip(np.round((centres + side / (2 * fps)) * clip.sample_rate), 0, samples.size).astype(int)
        for side in (-1, 1)
    )
    mean_square = (energy[last] - energy[first]) / np.maximum(last - first, 1)
    return np.maximum(10.0 * np.log10(np.maximum(mean_square, 1e-20)), SILENT_DB)


class LoudnessFloor(Estimator):
    """jawOpen from the loudness alone: :func:`loudness_envelope` mapped linearly from
    :data:`SILENT_DB` (0) to 0 dB (1)."""

    family = "loudness"
    input_kind = "audio"
    data_free = True
    trainable = False

    @property
    def channels(self) -> tuple[str, ...]:
        return ("jawOpen",)

    @property
    def postprocessing(self) -> str:
        return "audio"

    def _fit(self, corpus, run: FitRun) -> LoudnessFloor:
        raise VispeechError("the loudness floor learns nothing")

    def predict(self, clip: AudioClip, fps: float) -> Track:
        """A track of ``clip.n_frames(fps)`` frames of jawOpen in [0, 1]."""
        level = loudness_envelope(clip, fps)
        return Track((1.0 - level / SILENT_DB)[:, None], self.channels, fps)

    def _learned_state(self) -> None:
        return None

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        raise ValueError("the loudness floor has no learned state")
