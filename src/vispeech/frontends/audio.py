"""Reading speech audio files (WAV, FLAC and the other formats libsndfile knows)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError


def read_audio(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """The samples of an audio file as float32 in [-1, 1], mono (channels averaged), and its sample rate in Hz."""
    import soundfile

    _check_exists(path)
    try:
        samples, sample_rate = soundfile.read(path, dtype="float32", always_2d=True)
    except (OSError, RuntimeError) as exc:  # libsndfile errors are RuntimeErrors
        raise VispeechError(f"cannot read audio {path}: {exc}") from None
    if samples.size == 0:
        raise VispeechError(f"audio file {path} is empty")
    return samples.mean(axis=1), int(sample_rate)


def audio_duration(path: str | os.PathLike) -> float:
    """Length of an audio file in seconds, read from its header."""
    import soundfile

    _check_exists(path)
    try:
        info = soundfile.info(path)
    except (OSError, RuntimeError) as exc:
        raise VispeechError(f"cannot read audio {path}: {exc}") from None
    if info.frames == 0:
        raise VispeechError(f"audio file {path} is empty")
    return info.frames / info.samplerate


def _check_exists(path: str | os.PathLike) -> None:
    if not Path(path).is_file():
        raise VispeechError(f"audio file not found: {path}")


def to_pcm16(samples: np.ndarray) -> np.ndarray:
    """Float samples in [-1, 1] as 16-bit little-endian PCM (clipped), the one conversion
    for WAV files and streamed audio alike."""
    return np.clip(np.asarray(samples) * 32767.0, -32768, 32767).astype("<i2")


def wav_bytes(samples: np.ndarray, sample_rate: int) -> bytes:
    """A mono 16-bit PCM WAV file of ``samples`` (floats in [-1, 1]) in memory."""
    import io
    import wave

    buffer = io.BytesIO()
    with wave.open(buffer, "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(int(sample_rate))
        out.writeframes(to_pcm16(samples).tobytes())
    return buffer.getvalue()
