"""How an audio network reads audio: spectral features, speaker normalisation, frame stacking.

Features (:mod:`vispeech.frontends.features`) come at 100 frames per second; a network at
``fps`` frames per second reads ``stack = 100 / fps`` of them per frame, side by side: frame
k (at ``k / fps`` s) takes feature frames ``stack·k .. stack·k + stack - 1``, so it sees
``(stack - 1) · 10 ms`` ahead of its own time plus half the 25 ms analysis window. Before
stacking, features are normalised per dimension:

- ``"running"`` (default): causally, by the mean and variance of the audio heard so far pooled
  with the training data's (:func:`~vispeech.frontends.features.running_normalize`), which
  removes much of a new voice's and microphone's spectral colour and streams exactly;
- ``"global"``: by the training data's mean and variance only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.features import FEATURE_KINDS, FRAME_RATE, running_normalize, spectral_features

NORMALIZATIONS = ("running", "global")


@dataclass
class AudioEncoding:
    """Audio → one input vector per network frame (see the module docstring).

    ``mean``/``std`` are the training features' statistics (per dimension); ``prior_seconds``
    is how much audio the running normalisation's prior is worth.
    """

    kind: str = "log-mel"
    n_mels: int = 80
    n_mfcc: int = 13
    fps: float = 50.0
    normalize: str = "running"
    prior_seconds: float = 2.0
    mean: list[float] = field(default_factory=list)
    std: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.kind not in FEATURE_KINDS:
            raise VispeechError(f"unknown audio feature {self.kind!r} (use {', '.join(FEATURE_KINDS)})")
        if self.normalize not in NORMALIZATIONS:
            raise VispeechError(f"normalize must be one of {', '.join(NORMALIZATIONS)}, got {self.normalize!r}")
        stack = FRAME_RATE / self.fps
        if not (stack >= 1 and abs(stack - round(stack)) < 1e-9):
            raise VispeechError(f"an audio network's fps must divide {FRAME_RATE:g} (100, 50, 25, 20, ...), got {self.fps}")
        if not (isinstance(self.n_mels, int) and 8 <= self.n_mels <= 256 and isinstance(self.n_mfcc, int)
                and 1 <= self.n_mfcc <= self.n_mels):
            raise VispeechError("n_mels must be within 8..256 and n_mfcc within 1..n_mels")

    @property
    def stack(self) -> int:
        """Feature frames per network frame."""
        return round(FRAME_RATE / self.fps)

    @property
    def dims(self) -> int:
        """Feature dimensions per feature frame."""
        return self.n_mels if self.kind == "log-mel" else self.n_mfcc

    @property
    def size(self) -> int:
        """Values per network input frame."""
        return self.dims * self.stack

    def features(self, power: np.ndarray) -> np.ndarray:
        """Un-normalised features of power spectra (``(frames, dims)`` at 100 fps)."""
        return spectral_features(power, self.kind, self.n_mels, self.n_mfcc)

    def with_statistics(self, features: list[np.ndarray]) -> AudioEncoding:
        """A copy holding the mean and standard deviation of ``features`` (the training set's)."""
        stacked = np.concatenate(features)
        return AudioEncoding(self.kind, self.n_mels, self.n_mfcc, self.fps, self.normalize, self.prior_seconds,
                             stacked.mean(axis=0).tolist(), np.maximum(stacked.std(axis=0), 1e-3).tolist())

    def normalise(self, features: np.ndarray, state=None) -> tuple[np.ndarray, object]:
        """Normalised features and the running state to continue from (``None`` for global)."""
        mean, std = np.asarray(self.mean), np.asarray(self.std)
        if len(mean) != self.dims:
            raise VispeechError("the audio encoding has no training statistics (fit the model first)")
        if self.normalize == "global":
            return ((features - mean) / std).astype(np.float32), None
        return running_normalize(features, mean, std, self.prior_seconds * FRAME_RATE, state)

    def stacked(self, normalised: np.ndarray, n_frames: int) -> np.ndarray:
        """``(n_frames, size)`` network inputs from normalised feature frames (the last one
        repeated where they run out)."""
        needed = n_frames * self.stack
        if len(normalised) == 0:
            normalised = np.zeros((1, self.dims), dtype=np.float32)
        index = np.minimum(np.arange(needed), len(normalised) - 1)
        return normalised[index].reshape(n_frames, self.size)

    def encode(self, power: np.ndarray, n_frames: int) -> np.ndarray:
        """Network inputs for ``n_frames`` frames of the audio whose power spectra are ``power``."""
        normalised, _ = self.normalise(self.features(power))
        return self.stacked(normalised, n_frames)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "n_mels": self.n_mels, "n_mfcc": self.n_mfcc, "fps": self.fps,
                "normalize": self.normalize, "prior_seconds": self.prior_seconds,
                "mean": list(self.mean), "std": list(self.std)}

    @classmethod
    def from_dict(cls, data: dict) -> AudioEncoding:
        return cls(**data)
