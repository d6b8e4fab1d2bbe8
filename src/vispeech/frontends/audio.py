"""Speech audio: reading files (WAV, FLAC, MP3, OGG and the other formats libsndfile knows), from
a path or as the bytes of an upload, the checked mono clip every audio path takes, conversions
to 16-bit PCM, and the sample rates of live audio. libsndfile reads in a worker process
(:mod:`vispeech.frontends.isolation`): a file it crashes or hangs on is a
:class:`~vispeech.errors.NativeFailure`."""

from __future__ import annotations

import functools
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vispeech.alignment.phones import n_frames_for
from vispeech.errors import VispeechError
from vispeech.frontends.isolation import run_isolated
from vispeech.limits import MAX_DURATION_S

MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 4_000, 384_000
"""Sample rates (Hz) an audio input may have."""


@dataclass(frozen=True)
class AudioClip:
    """Mono speech audio: float32 ``samples`` in [-1, 1] at ``sample_rate`` Hz.

    Build it with :meth:`from_array` or :meth:`read`, which check the input: at least one
    sample, finite values, a sample rate within [:data:`MIN_SAMPLE_RATE`,
    :data:`MAX_SAMPLE_RATE`] and at most :data:`~vispeech.limits.MAX_DURATION_S` seconds.
    """

    samples: np.ndarray
    sample_rate: int

    @classmethod
    def from_array(cls, samples: np.ndarray, sample_rate: int, where: str = "audio") -> AudioClip:
        """A checked clip of ``samples`` (floats in [-1, 1] or 16-bit integers; 1-D or
        ``(samples, channels)``, channels averaged) at ``sample_rate`` Hz; values beyond
        [-1, 1] are clipped."""
        array = np.asarray(samples)
        if array.dtype == np.int16:
            array = array.astype(np.float32) / 32768.0
        elif not np.issubdtype(array.dtype, np.floating):  # int32, bool, complex: a scale we cannot know
            raise VispeechError(f"{where} must be floats in [-1, 1] or 16-bit integers, got {array.dtype}")
        if array.ndim == 2 and array.shape[1] > array.shape[0]:
            raise VispeechError(f"{where} has shape {array.shape}: give (samples, channels), not (channels, samples)")
        if array.ndim == 2 and array.shape[1] > 0:
            array = array.mean(axis=1)
        if array.ndim != 1:
            raise VispeechError(f"{where} must be 1-D or (samples, channels), got shape {np.shape(samples)}")
        if array.size == 0:
            raise VispeechError(f"{where} is empty")
        if not (isinstance(sample_rate, int | np.integer) and MIN_SAMPLE_RATE <= sample_rate <= MAX_SAMPLE_RATE):
            raise VispeechError(
                f"{where}: sample rate must be a whole number of Hz within "
                f"{MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE}, got {sample_rate!r}"
            )
        duration = array.size / sample_rate
        if duration > MAX_DURATION_S:
            raise VispeechError(f"{where} lasts {duration:.1f} s; the limit is {MAX_DURATION_S:g} s")
        array = array.astype(np.float32)
        if not np.all(np.isfinite(array)):
            raise VispeechError(f"{where} has non-finite samples")
        return cls(np.clip(array, -1.0, 1.0), int(sample_rate))

    @classmethod
    def read(cls, path: str | os.PathLike) -> AudioClip:
        """The checked clip of an audio file (see :func:`read_audio`)."""
        duration = audio_duration(path)
        if duration > MAX_DURATION_S:
            raise VispeechError(f"audio {path} lasts {duration:.1f} s; the limit is {MAX_DURATION_S:g} s")
        samples, sample_rate = read_audio(path)
        return cls.from_array(samples, sample_rate, where=f"audio {path}")

    @property
    def duration(self) -> float:
        """Length in seconds."""
        return self.samples.size / self.sample_rate

    def n_frames(self, fps: float) -> int:
        """Frames at ``fps`` that cover the clip (as a track of it has)."""
        return n_frames_for(self.duration, fps)

    def resampled(self, sample_rate: int) -> AudioClip:
        """The clip at ``sample_rate`` Hz (band-limited resampling by soxr's high quality, as
        librosa's ``soxr_hq``; ``ceil(samples · sample_rate / self.sample_rate)`` samples)."""
        if sample_rate == self.sample_rate:
            return self
        import soxr

        samples = soxr.resample(self.samples, self.sample_rate, sample_rate, quality="HQ")
        expected = math.ceil(self.samples.size * sample_rate / self.sample_rate)
        samples = np.pad(samples[:expected], (0, max(0, expected - samples.size)))
        return AudioClip(np.clip(samples, -1.0, 1.0).astype(np.float32), int(sample_rate))

    def wav_bytes(self) -> bytes:
        """The clip as a mono 16-bit PCM WAV file in memory."""
        return wav_bytes(self.samples, self.sample_rate)


def read_audio(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """The samples of an audio file as float32 in [-1, 1], mono (channels averaged), and its sample rate in Hz."""
    _check_exists(path)
    samples, sample_rate = _decoded(str(path), f"cannot read audio {path}", f"audio {path}")
    if samples.size == 0:
        raise VispeechError(f"audio file {path} is empty")
    return samples.mean(axis=1), int(sample_rate)


def audio_duration(path: str | os.PathLike) -> float:
    """Length of an audio file in seconds, read from its header."""
    _check_exists(path)
    frames, sample_rate, _ = _header(str(path), f"cannot read audio {path}", f"audio {path}")
    if frames == 0:
        raise VispeechError(f"audio file {path} is empty")
    return frames / sample_rate


MAX_UPLOAD_SAMPLES = int(MAX_DURATION_S * 48_000 * 2)
"""Most samples (all channels together) an uploaded file may decode to: 600 s of stereo at 48 kHz."""


def probe_upload(data: bytes) -> tuple[str, float]:
    """The SHA-256 (hex) and length in seconds of an uploaded audio file, read from its header;
    :class:`VispeechError` when it is empty, not audio, too long or too large decoded."""
    if not data:
        raise VispeechError("the request body is empty: send an audio file (WAV, FLAC, MP3 or OGG) as the body")
    frames, sample_rate, channels = _header(
        data, "the request body is not an audio file this server reads (WAV, FLAC, MP3, OGG)", "the uploaded audio"
    )
    if frames <= 0 or sample_rate <= 0:
        raise VispeechError("the uploaded audio is empty")
    duration = frames / sample_rate
    if duration > MAX_DURATION_S:
        raise VispeechError(f"the uploaded audio lasts {duration:.1f} s; the limit is {MAX_DURATION_S:g} s")
    if frames * channels > MAX_UPLOAD_SAMPLES:
        raise VispeechError(
            f"the uploaded audio holds {frames * channels} samples ({channels} channels "
            f"at {sample_rate} Hz); the limit is {MAX_UPLOAD_SAMPLES} (600 s of stereo at 48 kHz)"
        )
    import hashlib  # here: OpenSSL's library is loaded only for uploads

    return hashlib.sha256(data).hexdigest(), duration


def read_upload(data: bytes) -> AudioClip:
    """The checked clip of an uploaded audio file (see :func:`probe_upload`), channels averaged."""
    samples, sample_rate = _decoded(data, "cannot read the uploaded audio", "the uploaded audio")
    return AudioClip.from_array(samples, sample_rate, where="the uploaded audio")


def _header(source: str | bytes, failure: str, what: str) -> tuple[int, int, int]:
    """libsndfile's frames, sample rate and channels of an audio file (its path or its bytes), read
    in a worker process; :class:`VispeechError` ``"<failure>: <why>"``."""
    return run_isolated("libsndfile", what, _read_sound, source, failure, True)


def _decoded(source: str | bytes, failure: str, what: str) -> tuple[np.ndarray, int]:
    """The samples (float32, ``(samples, channels)``) and sample rate of an audio file (its path or
    its bytes), decoded by libsndfile in a worker process; :class:`VispeechError` as :func:`_header`."""
    return run_isolated("libsndfile", what, _read_sound, source, failure, False)


def _read_sound(source: str | bytes, failure: str, header: bool):
    """In a worker: :func:`_header` (``header``) or :func:`_decoded` of ``source``."""
    import soundfile

    try:
        if header:
            info = soundfile.info(io.BytesIO(source) if isinstance(source, bytes) else source)
            return info.frames, info.samplerate, info.channels
        return soundfile.read(
            io.BytesIO(source) if isinstance(source, bytes) else source, dtype="float32", always_2d=True
        )
    except (RuntimeError, OSError, EOFError) as exc:  # libsndfile's errors are RuntimeErrors
        raise VispeechError(f"{failure}: {getattr(exc, 'error_string', None) or exc}") from None


def _check_exists(path: str | os.PathLike) -> None:
    if Path(path).is_dir():
        raise VispeechError(f"audio path {path} is a folder, not a file")
    if not Path(path).is_file():
        raise VispeechError(f"audio file not found: {path}")


def to_pcm16(samples: np.ndarray) -> np.ndarray:
    """Float samples in [-1, 1] as 16-bit little-endian PCM (clipped), the one conversion
    for WAV files and streamed audio alike."""
    return np.clip(np.asarray(samples) * 32767.0, -32768, 32767).astype("<i2")


def wav_bytes(samples: np.ndarray, sample_rate: int) -> bytes:
    """A mono 16-bit PCM WAV file of ``samples`` (floats in [-1, 1], or 16-bit PCM as it is) in memory."""
    import wave

    samples = np.asarray(samples)
    pcm = samples.astype("<i2") if samples.dtype == np.int16 else to_pcm16(samples)
    buffer = io.BytesIO()
    with wave.open(buffer, "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(int(sample_rate))
        out.writeframes(pcm.tobytes())
    return buffer.getvalue()


def check_sample_rate(sample_rate: int) -> int:
    """``sample_rate`` if it is a whole number of Hz that live audio may have; :class:`VispeechError` if not."""
    if not (isinstance(sample_rate, int) and MIN_SAMPLE_RATE <= sample_rate <= MAX_SAMPLE_RATE):
        raise VispeechError(
            f"sample rate must be a whole number of Hz within {MIN_SAMPLE_RATE}..{MAX_SAMPLE_RATE}, got {sample_rate!r}"
        )
    return sample_rate


@functools.lru_cache(maxsize=64)
def resampler_delay(rate: int, model_rate: int) -> float:
    """The output (seconds) soxr's streaming resampler (HQ) from ``rate`` to ``model_rate`` Hz holds
    back on average, fed 4 s of audio in 20 ms chunks (it works in blocks, so the amount varies
    around that): about 21–23 ms from 22.05–48 kHz to 16 kHz, 63 ms from 8 kHz."""
    import soxr

    probe = soxr.ResampleStream(rate, model_rate, 1, dtype="float32", quality="HQ")
    held = []
    for _ in range(200):
        probe.resample_chunk(np.zeros(max(1, rate // 50), np.float32))
        held.append(probe.delay())
    return float(np.mean(held)) / model_rate
