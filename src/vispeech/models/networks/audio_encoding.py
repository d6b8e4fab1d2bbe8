"""How an audio network reads audio: spectral features, speaker normalisation, frame stacking.

Features (:mod:`vispeech.frontends.features`) come at 100 frames per second; a network at
``fps`` frames per second reads ``stack = 100 / fps`` of them per frame, side by side: frame
k (at ``k / fps`` s) takes feature frames ``stack·k .. stack·k + stack - 1``, so it sees
``(stack - 1) · 10 ms`` ahead of its own time plus half the 25 ms analysis window. Before
stacking, features are normalised per dimension:

- ``"running"`` (default): causally, by the mean and variance of the audio heard so far pooled
  with the training data's (:func:`~vispeech.frontends.features.running_normalize`), which
  removes much of a new voice's and microphone's spectral colour and streams exactly; with
  ``memory_seconds``, once that much audio has been heard, by the last ``memory_seconds`` of
  it alone, so that deep into a long recording or stream they follow the voice and the
  microphone as they are now (a clip no longer than that is normalised as without it);
- ``"global"``: by the training data's mean and variance only.

The running normalisation's prior is the training audio's, at its recording level, and it
weighs most in a clip's first seconds: a quiet recording then reads as near silence (on
grid_s1's validation utterances 20 dB down, the log-mel CNN's jawOpen r fell from 0.83 to
0.66). With a ``level_range`` (the span of the training clips'
:func:`~vispeech.frontends.features.speech_level`), :meth:`AudioEncoding.matched` gains a
whole clip whose level lies outside it to its nearer end, as if its microphone had been set
for the training audio, and leaves a clip within it as it is, bit for bit; the networks apply
it when they predict a whole clip (training reads its clips as they are). A stream cannot know
its level before it has heard the speech and is not gained: its prior weighs less as the voice
is heard, and after ``memory_seconds`` not at all.

``kind="encoder"`` reads a pretrained speech encoder's hidden states instead
(:mod:`vispeech.frontends.encoder`, from the folder ``encoder``): ``layers`` hidden states
of ``width`` values per frame, side by side (layer-major) in one input vector of
``layers · width`` values, which the network fuses (a learned softmax-weighted sum of the
layers, PhISANet's All-Enc); one hidden-state frame is one network frame (the network checks
that ``fps`` is the encoders' 50). They are always standardised per dimension by the
training data's statistics (``normalize`` is ``"global"``): the self-supervised encoders
were trained across thousands of voices and read a per-clip normalised waveform, a running
normalisation of thousands of dimensions would be noisy, and global statistics keep a
streamed frame independent of the audio before it; standardising also puts every layer on
one scale, so the fusion weights compare layers rather than their magnitudes. A Whisper
encoder gives one state, read after its first ``encoder_depth`` transformer layers (0: all;
:mod:`vispeech.frontends.whisper`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from itertools import pairwise
from typing import cast

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.features import (
    FEATURE_KINDS,
    FRAME_RATE,
    running_normalize_together,
    spectral_features,
    speech_level,
)

NORMALIZATIONS = ("running", "global")
MAX_MEMORY_SECONDS = 60.0
"""The most audio (s) a running normalisation with a memory keeps: a live stream holds it."""
KINDS = (*FEATURE_KINDS, "encoder")
"""The audio features a network can read."""


@dataclass
class AudioEncoding:
    """Audio → one input vector per network frame (see the module docstring).

    ``mean``/``std`` are the training features' statistics (per dimension); ``prior_seconds``
    is how much audio the running normalisation's prior is worth, ``memory_seconds`` how much of
    the audio heard it remembers (the last seconds; 0: all of it; see
    :func:`~vispeech.frontends.features.running_normalize`); ``level_range`` the lowest and
    highest :func:`~vispeech.frontends.features.speech_level` (dB) a whole clip is gained into
    (empty: none; spectral features only). ``encoder`` (the folder, as
    given), ``encoder_depth`` (a Whisper encoder's layers read; 0: all), ``layers`` and ``width``
    describe a speech encoder's hidden states (``kind="encoder"``; ``layers`` and ``width`` are 0
    until the encoder is loaded at fit).
    """

    kind: str = "log-mel"
    n_mels: int = 80
    n_mfcc: int = 13
    fps: float = 50.0
    normalize: str = "running"
    prior_seconds: float = 2.0
    memory_seconds: float = 0.0
    level_range: list[float] = field(default_factory=list)
    mean: list[float] = field(default_factory=list)
    std: list[float] = field(default_factory=list)
    encoder: str | None = None
    encoder_depth: int = 0
    layers: int = 0
    width: int = 0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise VispeechError(f"unknown audio feature {self.kind!r} (use {', '.join(KINDS)})")
        if (self.kind == "encoder") != (self.encoder is not None):
            raise VispeechError(
                "features=encoder needs encoder=FOLDER (a local wav2vec 2.0 / WavLM / HuBERT "
                "model folder), and encoder= needs features=encoder"
            )
        if self.kind == "encoder":
            if not (isinstance(self.encoder, str) and self.encoder):
                raise VispeechError(f"encoder must be the path of a model folder, got {self.encoder!r}")
            if self.normalize != "global":
                raise VispeechError(
                    f"speech encoder features are normalised globally, got normalize {self.normalize!r}"
                )
        if not (isinstance(self.encoder_depth, int) and 0 <= self.encoder_depth <= 64):
            raise VispeechError(f"encoder_depth must be a whole number within 0..64, got {self.encoder_depth!r}")
        if self.encoder_depth and self.kind != "encoder":
            raise VispeechError("encoder_depth needs features=encoder")
        if self.normalize not in NORMALIZATIONS:
            raise VispeechError(f"normalize must be one of {', '.join(NORMALIZATIONS)}, got {self.normalize!r}")
        if not (isinstance(self.prior_seconds, int | float) and 0 <= self.prior_seconds < math.inf):
            raise VispeechError(f"prior_seconds must be a number of seconds >= 0, got {self.prior_seconds!r}")
        if not (isinstance(self.memory_seconds, int | float) and 0 <= self.memory_seconds <= MAX_MEMORY_SECONDS):
            raise VispeechError(
                f"memory_seconds must be a number of seconds within 0..{MAX_MEMORY_SECONDS:g}, "
                f"got {self.memory_seconds!r}"
            )
        if self.level_range:
            if self.kind == "encoder":
                raise VispeechError("level_range needs spectral features (a speech encoder reads the waveform)")
            if not (
                len(self.level_range) == 2
                and all(isinstance(v, int | float) and math.isfinite(v) for v in self.level_range)
                and self.level_range[0] <= self.level_range[1]
            ):
                raise VispeechError(f"level_range must be [lowest, highest] dB, got {self.level_range!r}")
        if not (isinstance(self.fps, int | float) and self.fps > 0):
            raise VispeechError(f"an audio network's fps must be a number > 0, got {self.fps!r}")
        stack = FRAME_RATE / self.fps
        if not (stack >= 1 and abs(stack - round(stack)) < 1e-9):
            raise VispeechError(
                f"an audio network's fps must divide {FRAME_RATE:g} (100, 50, 25, 20, ...), got {self.fps}"
            )
        if not (
            isinstance(self.n_mels, int)
            and 8 <= self.n_mels <= 256
            and isinstance(self.n_mfcc, int)
            and 1 <= self.n_mfcc <= self.n_mels
        ):
            raise VispeechError("n_mels must be within 8..256 and n_mfcc within 1..n_mels")

    @property
    def stack(self) -> int:
        """Feature frames per network frame."""
        return round(self.frame_rate / self.fps)

    @property
    def dims(self) -> int:
        """Feature dimensions per feature frame."""
        if self.kind == "encoder":
            return self.layers * self.width
        return self.n_mels if self.kind == "log-mel" else self.n_mfcc

    @property
    def size(self) -> int:
        """Values per network input frame."""
        return self.dims * self.stack

    @property
    def frame_rate(self) -> float:
        """Feature frames per second (an encoder's hidden states come at the network's rate)."""
        return self.fps if self.kind == "encoder" else FRAME_RATE

    def features(self, source: np.ndarray) -> np.ndarray:
        """Un-normalised ``(frames, dims)`` float32 features at :attr:`frame_rate`: of power
        spectra, or (``kind="encoder"``) of hidden states ``(layers, frames, width)``, flattened per frame."""
        if self.kind == "encoder":
            if source.shape[0] != self.layers or source.shape[2] != self.width:
                raise VispeechError(
                    f"the speech encoder gives {source.shape[0]} hidden states of {source.shape[2]} "
                    f"values; the model was trained on {self.layers} of {self.width}"
                )
            return np.ascontiguousarray(source.transpose(1, 0, 2), dtype=np.float32).reshape(source.shape[1], -1)
        return spectral_features(source, self.kind, self.n_mels, self.n_mfcc)

    def with_statistics(self, features: Iterable[np.ndarray]) -> AudioEncoding:
        """A copy holding the per-dimension mean and standard deviation of ``features`` (the
        training set's ``(frames, dims)`` arrays, taken one at a time)."""
        count, total, squares = 0, 0.0, 0.0
        for frames in features:
            x = np.asarray(frames, dtype=np.float64)
            count, total, squares = count + len(x), total + x.sum(axis=0), squares + (x**2).sum(axis=0)
        mean = cast(np.ndarray, total / count)  # the sums are arrays once a frame came (none: ZeroDivisionError)
        std = np.sqrt(np.maximum(squares / count - mean**2, 0.0))
        return replace(self, mean=mean.tolist(), std=np.maximum(std, 1e-3).tolist())

    def with_level_range(self, powers: Iterable[np.ndarray]) -> AudioEncoding:
        """A copy whose ``level_range`` spans the lowest to the highest
        :func:`~vispeech.frontends.features.speech_level` of the training clips' power spectra
        ``powers`` (taken one at a time)."""
        levels = [speech_level(power, self.n_mels) for power in powers]
        return replace(self, level_range=[min(levels), max(levels)])

    def matched(self, power: np.ndarray) -> np.ndarray:
        """A whole clip's power spectra ``(frames, bins)`` gained into ``level_range`` (the
        same array when its level lies within it, without one, or for no frames)."""
        if not self.level_range or not len(power):
            return power
        level = speech_level(power, self.n_mels)
        low, high = self.level_range
        gain = min(max(level, low), high) - level
        return power * np.float32(10.0 ** (gain / 10.0)) if gain else power

    def normalise(self, features: np.ndarray, state=None) -> tuple[np.ndarray, object]:
        """Normalised features and the running state to continue from (``None`` for global)."""
        (out,), (state,) = self.normalise_together([features], [state])
        return out, state

    def normalise_together(self, features: Sequence[np.ndarray], states: Sequence) -> tuple[list[np.ndarray], list]:
        """:meth:`normalise` of several streams' next features at once, ``states[i]`` continuing ``features[i]``."""
        mean, std = np.asarray(self.mean), np.asarray(self.std)
        if len(mean) != self.dims:
            raise VispeechError("the audio encoding has no training statistics (fit the model first)")
        if self.normalize == "running":
            rate = self.frame_rate
            return running_normalize_together(
                features, mean, std, self.prior_seconds * rate, states, round(self.memory_seconds * rate)
            )
        out = np.subtract(np.concatenate(features), mean.astype(np.float32), dtype=np.float32)
        out /= std.astype(np.float32)
        bounds = np.cumsum([0, *map(len, features)]).tolist()
        return [out[a:b] for a, b in pairwise(bounds)], [None] * len(features)

    def stacked(self, normalised: np.ndarray, n_frames: int) -> np.ndarray:
        """``(n_frames, size)`` network inputs from normalised feature frames (the last one
        repeated where they run out)."""
        needed = n_frames * self.stack
        if len(normalised) == needed:
            return normalised.reshape(n_frames, self.size)
        if len(normalised) == 0:
            normalised = np.zeros((1, self.dims), dtype=np.float32)
        index = np.minimum(np.arange(needed), len(normalised) - 1)
        return normalised[index].reshape(n_frames, self.size)

    def encode(self, source: np.ndarray, n_frames: int) -> np.ndarray:
        """Network inputs for ``n_frames`` frames of the audio whose power spectra (or
        encoder hidden states) are ``source``."""
        normalised, _ = self.normalise(self.features(source))
        return self.stacked(normalised, n_frames)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "n_mels": self.n_mels,
            "n_mfcc": self.n_mfcc,
            "fps": self.fps,
            "normalize": self.normalize,
            "prior_seconds": self.prior_seconds,
            "memory_seconds": self.memory_seconds,
            "level_range": list(self.level_range),
            "mean": list(self.mean),
            "std": list(self.std),
            "encoder": self.encoder,
            "encoder_depth": self.encoder_depth,
            "layers": self.layers,
            "width": self.width,
        }

    @classmethod
    def from_dict(cls, data: dict) -> AudioEncoding:
        return cls(**data)
