"""What happens to a voice between a mouth and vispeech: other vocal tracts, rooms, noise,
telephones and lossy codecs, as functions on sample arrays (mono float32 in [-1, 1]).

They make one speaker's recordings sound like the voices users send, for training
(:mod:`vispeech.corpus.augment`). Each takes ``samples`` at ``rate`` Hz and returns the same
number of samples at the same rate (:func:`time_stretch` aside), peak-limited to [-1, 1].
"""

from __future__ import annotations

import io

import numpy as np

from vispeech.errors import VispeechError

MIN_PITCH, MAX_PITCH = 60.0, 600.0
"""Hz: the pitch range Praat looks for a voice in."""


def _limited(samples: np.ndarray) -> np.ndarray:
    peak = float(np.max(np.abs(samples))) if len(samples) else 0.0
    out = samples / peak * 0.95 if peak > 0.95 else samples
    return np.asarray(out, dtype=np.float32)


def shift_voice(samples: np.ndarray, rate: int, pitch: float = 0.0, formants: float = 1.0) -> np.ndarray:
    """The voice with its pitch moved by ``pitch`` semitones and its formants (the spectral
    envelope: the vocal tract's length) scaled by ``formants`` (1.15: a tract 13 % shorter),
    independently: Praat's "Change gender" (PSOLA resynthesis, through parselmouth). Audio
    without a voiced stretch comes back with its formants moved only."""
    import parselmouth
    from parselmouth.praat import call

    if not 0.7 <= formants <= 1.4:
        raise VispeechError(f"formant factor must lie in [0.7, 1.4], got {formants}")
    sound = parselmouth.Sound(np.asarray(samples, dtype=np.float64), sampling_frequency=rate)
    median = call(
        sound.to_pitch(time_step=0.01, pitch_floor=MIN_PITCH, pitch_ceiling=MAX_PITCH),
        "Get quantile",
        0,
        0,
        0.5,
        "Hertz",
    )
    target = median * 2 ** (pitch / 12) if np.isfinite(median) else 0.0
    changed = call(sound, "Change gender", MIN_PITCH, MAX_PITCH, formants, target, 1.0, 1.0)
    out = changed.values[0][: len(samples)]
    return _limited(np.pad(out, (0, len(samples) - len(out))))


def time_stretch(samples: np.ndarray, speed: float) -> np.ndarray:
    """The speech ``speed`` times as fast (``len / speed`` samples), its pitch kept (librosa's
    phase vocoder): a faster or slower talker."""
    import librosa

    if not 0.5 <= speed <= 2.0:
        raise VispeechError(f"speed must lie in [0.5, 2], got {speed}")
    return _limited(librosa.effects.time_stretch(np.asarray(samples, dtype=np.float32), rate=speed))


def reverberate(samples: np.ndarray, rate: int, rt60: float, wet: float, rng: np.random.Generator) -> np.ndarray:
    """The voice in a room: convolved with a synthetic impulse response (a direct path, then
    Gaussian noise decaying by 60 dB in ``rt60`` seconds), mixed ``wet`` (0..1) with the dry
    voice at equal energy."""
    from scipy.signal import fftconvolve

    n = max(2, int(rt60 * rate))
    tail = rng.standard_normal(n) * np.exp(-6.9 * np.arange(n) / n)
    tail[0] = 0.0
    tail /= np.sqrt(np.sum(tail**2))
    x = np.asarray(samples, dtype=np.float64)
    room = fftconvolve(x, tail)[: len(x)]
    dry_energy, room_energy = np.sum(x**2), np.sum(room**2)
    if room_energy > 0:
        room *= np.sqrt(dry_energy / room_energy)
    return _limited((1 - wet) * x + wet * room)


def add_noise(samples: np.ndarray, snr_db: float, rng: np.random.Generator, colour: float = 1.0) -> np.ndarray:
    """The voice with noise at ``snr_db`` dB below it (over the whole clip); the noise's power
    falls as ``1 / f ** colour`` (0 white, 1 pink, 2 brown)."""
    x = np.asarray(samples, dtype=np.float64)
    spectrum = np.fft.rfft(rng.standard_normal(len(x)))
    f = np.arange(len(spectrum), dtype=np.float64)
    f[0] = 1.0
    noise = np.fft.irfft(spectrum / f ** (colour / 2), n=len(x))
    power, noise_power = np.mean(x**2), np.mean(noise**2)
    if power == 0 or noise_power == 0:
        return _limited(x)
    return _limited(x + noise * np.sqrt(power / noise_power / 10 ** (snr_db / 10)))


def telephone(samples: np.ndarray, rate: int) -> np.ndarray:
    """The voice over a telephone line: band-passed to 300-3400 Hz (zero phase), sampled at 8 kHz with
    8-bit μ-law (G.711), back at ``rate``."""
    import librosa
    from scipy.signal import butter, sosfiltfilt

    sos = butter(4, [300, min(3400, 0.45 * rate)], btype="bandpass", fs=rate, output="sos")
    x = sosfiltfilt(sos, np.asarray(samples, dtype=np.float64)).astype(np.float32)
    narrow = librosa.resample(x, orig_sr=rate, target_sr=8000, res_type="soxr_hq")
    peak = max(float(np.max(np.abs(narrow))), 1e-9)
    coded = librosa.mu_expand(librosa.mu_compress(narrow / peak, mu=255, quantize=True), mu=255, quantize=True) * peak
    back = librosa.resample(coded.astype(np.float32), orig_sr=8000, target_sr=rate, res_type="soxr_hq")
    return _limited(np.pad(back, (0, max(0, len(samples) - len(back))))[: len(samples)])


CODECS = ("mp3", "opus", "vorbis")
"""Lossy codecs :func:`lossy` passes a voice through (libsndfile's)."""


def lossy(samples: np.ndarray, rate: int, codec: str, quality: float) -> np.ndarray:
    """The voice encoded and decoded by a lossy ``codec`` of :data:`CODECS` (libsndfile) at
    ``quality`` from 0 (smallest file) to 1."""
    import soundfile

    formats = {"mp3": ("MP3", "MPEG_LAYER_III"), "opus": ("OGG", "OPUS"), "vorbis": ("OGG", "VORBIS")}
    if codec not in formats:
        raise VispeechError(f"unknown codec {codec!r} (use {', '.join(CODECS)})")
    container, subtype = formats[codec]
    coding_rate = 48000 if codec == "opus" else rate  # Opus codes 8, 12, 16, 24 or 48 kHz; 48 is safe
    x = np.asarray(samples, dtype=np.float32)
    if coding_rate != rate:
        import librosa

        x = librosa.resample(x, orig_sr=rate, target_sr=coding_rate, res_type="soxr_hq")
    buffer = io.BytesIO()
    soundfile.write(
        buffer,
        x,
        coding_rate,
        format=container,
        subtype=subtype,
        compression_level=float(np.clip(1.0 - quality, 0.0, 1.0)),
    )
    buffer.seek(0)
    decoded, decoded_rate = soundfile.read(buffer, dtype="float32")
    if decoded_rate != rate:
        import librosa

        decoded = librosa.resample(decoded, orig_sr=decoded_rate, target_sr=rate, res_type="soxr_hq")
    decoded = decoded[: len(samples)]
    return _limited(np.pad(decoded, (0, len(samples) - len(decoded))))
