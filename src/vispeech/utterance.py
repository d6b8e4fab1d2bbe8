"""The utterance: one sentence's text, audio, phones and face track, recorded or synthesised."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vispeech.alignment.phones import PhoneSequence, Word
from vispeech.frontends.audio import read_audio, wav_bytes
from vispeech.motion.track import Track


@dataclass
class Utterance:
    """One sentence: transcript, audio, word timings, phones and face track.

    A corpus reader fills ``id``, ``text``, ``audio_path`` and ``duration`` (the audio's
    length in seconds, read on demand by :meth:`load_audio`), the recorded ``track`` and
    ``words``; alignment adds ``phones``. :func:`vispeech.pipeline.speak` fills ``text``,
    ``phones``, the animated ``track`` and the synthesised ``audio`` at ``sample_rate``.

    ``track`` holds the face channels (ARKit names, plus head pose ``headYaw``, ``headPitch``,
    ``headRoll`` in degrees and, where tracked, ``headX``, ``headY``, ``headZ`` in cm).
    ``frame_mask[k]`` is False where frame k was not tracked and its values were filled in;
    ``landmarks`` maps a name such as ``"lm13"`` (MediaPipe face-mesh index) to per-frame
    ``(n_frames, 3)`` image-normalised coordinates.
    """

    id: str = ""
    text: str = ""
    audio_path: Path | None = None
    duration: float | None = None
    track: Track | None = None
    words: list[Word] = field(default_factory=list)
    phones: PhoneSequence | None = None
    landmarks: dict[str, np.ndarray] | None = None
    frame_mask: np.ndarray | None = None
    audio: np.ndarray | None = None
    sample_rate: int | None = None

    def load_audio(self) -> tuple[np.ndarray, int]:
        """The audio as float samples in [-1, 1] (mono, channels averaged) and its sample rate in Hz."""
        if self.audio is not None:
            assert self.sample_rate is not None, "synthesised audio comes with its sample rate"
            return np.asarray(self.audio, dtype=np.float32), int(self.sample_rate)
        assert self.audio_path is not None, f"utterance {self.id!r} has neither audio nor an audio file"
        return read_audio(self.audio_path)

    def wav_bytes(self) -> bytes | None:
        """The audio as a 16-bit PCM WAV file in memory (``None`` without synthesised audio)."""
        if self.audio is None:
            return None
        assert self.sample_rate is not None, "synthesised audio comes with its sample rate"
        return wav_bytes(self.audio, int(self.sample_rate))
