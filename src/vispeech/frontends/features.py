"""Audio features for the audio models and the aligners, on NumPy: power spectra, log-mel
and MFCC at 100 frames per second, vocal-tract-length warping, and running normalisation.

Units and framing: audio at :data:`SAMPLE_RATE` Hz (other rates are resampled first); frame j
is centred at ``j * 10 ms`` (a 25 ms Hann window in a 512-point FFT, the signal padded with
zeros by half an FFT at both ends), so a clip of ``n`` samples has ``n // 160 + 1`` frames.
Log-mel values are natural logs of mel-band power (floor :data:`LOG_FLOOR`); MFCCs are the
DCT-II of log-mel in dB, as :func:`librosa.feature.mfcc` computes them.

The shipped audio models were trained on librosa's features (``librosa.stft`` with a periodic
Hann window, ``librosa.filters.mel`` with Slaney's mel scale and area normalisation,
``librosa.feature.mfcc``): the functions here compute the same numbers with the same float
operations (tests/test_audio_features.py compares them with librosa's), so that the core
install needs no librosa, numba or scikit-learn.

:class:`SpectrumStream` gives the same frames as :func:`power_spectrogram` for audio that
arrives in chunks: frame j once the samples up to ``j * 10 ms + 16 ms`` are in.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import TypeAlias, cast

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.turns import give_turn

SAMPLE_RATE = 16_000
"""Hz: the rate every feature is computed at."""
HOP = 160
"""Samples between frames (10 ms)."""
N_FFT = 512
WINDOW = 400
"""Samples in the analysis window (25 ms)."""
FRAME_RATE = SAMPLE_RATE / HOP
"""Feature frames per second (100)."""
LOG_FLOOR = 1e-6
"""Mel-band power below which log-mel is flat."""
FEATURE_KINDS = ("log-mel", "mfcc")
LEVEL_QUANTILE = 0.95
"""The share of a clip's frames quieter than its :func:`speech_level`."""
TURN_ROWS = 10_000
"""Frames (100 s of audio) whose spectra are computed between two turns given to others
(:func:`vispeech.turns.give_turn`)."""
LEVEL_FLOOR = 1e-12
"""Mel-band power below which :func:`speech_level` takes a band as flat (60 dB below :data:`LOG_FLOOR`)."""


def power_spectrogram(samples: np.ndarray) -> np.ndarray:
    """``(frames, N_FFT // 2 + 1)`` power spectra of float samples at :data:`SAMPLE_RATE` Hz."""
    padded = np.pad(np.asarray(samples, dtype=np.float32), N_FFT // 2)
    return _frames_power(padded)


def _frames_power(padded: np.ndarray) -> np.ndarray:
    """Power spectra of every whole frame of an already padded float32 signal (``librosa.stft(center=False)``)."""
    if len(padded) < N_FFT:
        return np.zeros((0, N_FFT // 2 + 1), dtype=np.float32)
    return _windows_power(np.lib.stride_tricks.sliding_window_view(padded, N_FFT)[::HOP])


def _windows_power(frames: np.ndarray) -> np.ndarray:
    """``(n, N_FFT // 2 + 1)`` power spectra of ``(n, N_FFT)`` float32 frames: windowed in
    float64, their spectra rounded to complex64, each row on its own (:data:`TURN_ROWS` at a time)."""
    power = np.empty((len(frames), N_FFT // 2 + 1), dtype=np.float32)
    for start in range(0, len(frames), TURN_ROWS):
        give_turn()
        spectrum = np.fft.rfft(frames[start : start + TURN_ROWS] * _window(), axis=1).astype(np.complex64)
        power[start : start + TURN_ROWS] = np.abs(spectrum) ** 2
    return power


@functools.cache
def _window() -> np.ndarray:
    """``(N_FFT,)`` periodic Hann window of :data:`WINDOW` samples centred in :data:`N_FFT`
    (``scipy.signal.get_window("hann", WINDOW)`` as librosa pads it)."""
    hann = 0.5 + 0.5 * np.cos(np.linspace(-np.pi, np.pi, WINDOW + 1))[:-1]
    side = (N_FFT - WINDOW) // 2
    return np.pad(hann, (side, N_FFT - WINDOW - side))


def warp_frequencies(power: np.ndarray, alpha: float, boundary: float = 4_800.0) -> np.ndarray:
    """Vocal-tract-length perturbation (Jaitly & Hinton 2013) of power spectra: frequency f
    moves to ``alpha * f`` up to ``boundary * min(alpha, 1) / alpha`` Hz, then linearly so
    that the Nyquist frequency stays put. ``alpha`` > 1 sounds like a shorter vocal tract."""
    if alpha == 1.0:
        return power
    if not 0.5 <= alpha <= 2.0:
        raise VispeechError(f"warp factor must lie in [0.5, 2], got {alpha}")
    nyquist = SAMPLE_RATE / 2
    freqs = np.linspace(0.0, nyquist, power.shape[1])
    knee = boundary * min(alpha, 1.0) / alpha
    warped = np.where(
        freqs <= knee, alpha * freqs, nyquist - (nyquist - alpha * knee) / (nyquist - knee) * (nyquist - freqs)
    )
    # the warped spectrum at f is the original one at warped⁻¹(f)
    source = np.interp(freqs, warped, freqs)
    position = source / nyquist * (power.shape[1] - 1)
    low = np.clip(np.floor(position).astype(int), 0, power.shape[1] - 2)
    frac = (position - low).astype(np.float32)
    return power[:, low] * (1 - frac) + power[:, low + 1] * frac


@functools.cache
def mel_filters(n_mels: int) -> np.ndarray:
    """``(n_mels, N_FFT // 2 + 1)`` Slaney mel filter bank from 20 Hz to 8 kHz."""
    return mel_filter_bank(SAMPLE_RATE, N_FFT, n_mels, fmin=20.0)


def mel_filter_bank(
    sample_rate: int, n_fft: int, n_mels: int, fmin: float = 0.0, fmax: float | None = None
) -> np.ndarray:
    """``(n_mels, n_fft // 2 + 1)`` float32 triangular filters on Slaney's mel scale from
    ``fmin`` to ``fmax`` Hz (default: half the sample rate), each scaled to unit area
    (``librosa.filters.mel(sr, n_fft, n_mels, fmin, fmax)``, its defaults ``htk=False``,
    ``norm="slaney"``)."""
    fmax = sample_rate / 2 if fmax is None else fmax
    bins = np.fft.rfftfreq(n_fft, 1.0 / sample_rate)
    edges = _mel_to_hz(np.linspace(_hz_to_mel(fmin), _hz_to_mel(fmax), n_mels + 2))
    widths = np.diff(edges)
    ramps = np.subtract.outer(edges, bins)
    weights = np.zeros((n_mels, len(bins)), dtype=np.float32)
    for i in range(n_mels):
        weights[i] = np.maximum(0, np.minimum(-ramps[i] / widths[i], ramps[i + 2] / widths[i + 1]))
    weights *= (2.0 / (edges[2 : n_mels + 2] - edges[:n_mels]))[:, np.newaxis]
    return weights


_MEL_STEP = 200.0 / 3
"""Hz per mel below :data:`_LOG_HZ` (Slaney's scale: linear up to 1 kHz, logarithmic above)."""
_LOG_HZ = 1000.0
_LOG_STEP = np.log(6.4) / 27.0
"""Natural-log frequency ratio per mel above :data:`_LOG_HZ`."""


def _hz_to_mel(hz: float) -> float:
    if hz < _LOG_HZ:
        return hz / _MEL_STEP
    return float(_LOG_HZ / _MEL_STEP + np.log(hz / _LOG_HZ) / _LOG_STEP)


def _mel_to_hz(mels: np.ndarray) -> np.ndarray:
    hz = _MEL_STEP * mels
    above = mels >= _LOG_HZ / _MEL_STEP
    hz[above] = _LOG_HZ * np.exp(_LOG_STEP * (mels[above] - _LOG_HZ / _MEL_STEP))
    return hz


def log_mel(power: np.ndarray, n_mels: int = 80) -> np.ndarray:
    """``(frames, n_mels)`` natural-log mel-band power of power spectra."""
    return np.log(np.maximum(power @ mel_filters(n_mels).T, LOG_FLOOR)).astype(np.float32)


def mfcc(log_mel_frames: np.ndarray, n_mfcc: int = 13) -> np.ndarray:
    """``(frames, n_mfcc)`` MFCCs of log-mel frames: the orthonormal DCT-II of the log-mel in dB
    over the bands (``librosa.feature.mfcc(S=dB, n_mfcc)``)."""
    decibels = log_mel_frames * (10.0 / np.log(10.0))
    return (decibels @ _dct_basis(log_mel_frames.shape[1])[:n_mfcc].T).astype(np.float32)


@functools.cache
def _dct_basis(n: int) -> np.ndarray:
    """``(n, n)`` orthonormal DCT-II matrix: row k is ``sqrt(2/n) cos(pi k (2i + 1) / 2n)`` over
    i, row 0 divided by sqrt(2) (``scipy.fft.dct(type=2, norm="ortho")`` to float64 rounding)."""
    k = np.arange(n)[:, np.newaxis]
    basis = np.cos(np.pi * k * (2 * np.arange(n) + 1) / (2 * n)) * np.sqrt(2.0 / n)
    basis[0] /= np.sqrt(2.0)
    return basis


def speech_level(power: np.ndarray, n_mels: int = 80) -> float:
    """A clip's level in dB from its power spectra ``(frames, bins)``: the
    :data:`LEVEL_QUANTILE` quantile over frames of the mean over ``n_mels`` bands of the log
    mel-band power, the level of its loud frames (vowels) whatever its share of silence. Its
    floor (:data:`LEVEL_FLOOR`) lies far below the features' so that a gain of g dB adds g to
    it. NaN for no frames."""
    if not len(power):
        return float("nan")
    bands = np.log(np.maximum(power @ mel_filters(n_mels).T, LEVEL_FLOOR))
    return float(np.quantile(np.mean(bands, axis=1, dtype=np.float64), LEVEL_QUANTILE) * (10.0 / np.log(10.0)))


def spectral_features(power: np.ndarray, kind: str = "log-mel", n_mels: int = 80, n_mfcc: int = 13) -> np.ndarray:
    """Features of ``kind`` (:data:`FEATURE_KINDS`) from power spectra, one row per frame."""
    if kind not in FEATURE_KINDS:
        raise VispeechError(f"unknown audio feature {kind!r} (use {', '.join(FEATURE_KINDS)})")
    frames = log_mel(power, n_mels)
    return frames if kind == "log-mel" else mfcc(frames, n_mfcc)


def audio_features(
    clip: AudioClip, kind: str = "log-mel", n_mels: int = 80, n_mfcc: int = 13, warp: float = 1.0
) -> np.ndarray:
    """Features of ``kind`` for a clip (resampled to :data:`SAMPLE_RATE`), ``(frames, dims)`` at
    :data:`FRAME_RATE`; ``warp`` is a vocal-tract-length factor (:func:`warp_frequencies`)."""
    power = power_spectrogram(clip.resampled(SAMPLE_RATE).samples)
    return spectral_features(warp_frequencies(power, warp), kind, n_mels, n_mfcc)


def running_normalize(
    features: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray,
    prior_frames: float,
    state: NormState | None = None,
    memory_frames: int = 0,
) -> tuple[np.ndarray, NormState]:
    """Causal per-dimension normalisation (speaker and channel normalisation that streams).

    Frame t is standardised by the mean and variance of the frames up to t, pooled with a prior
    (``mean``, ``std``: the training data's) worth ``prior_frames`` frames, so early frames lean
    on the prior and later ones on the voice heard so far. With ``memory_frames`` > 0, once
    more frames than that have been heard, the statistics are those of the last
    ``memory_frames`` frames alone (prior gone): deep into a long recording or stream they
    follow the voice and the microphone as they are now, not as they were minutes ago, and
    up to ``memory_frames`` frames nothing changes. ``state`` continues an earlier call (count,
    sum and sum of squares; with ``memory_frames``, the last frames heard); the new state is
    returned with the frames.
    """
    (out,), (state,) = running_normalize_together([features], mean, std, prior_frames, [state], memory_frames)
    return out, state


Sums = tuple[float, np.ndarray, np.ndarray]
"""Frames counted (with the prior's), their sum and sum of squares per dimension."""
NormState: TypeAlias = "Sums | _Window"
""":func:`running_normalize`'s state: the :data:`Sums` of all the frames heard; with
``memory_frames``, the last ``memory_frames`` (or fewer) frames heard and their sums."""


def running_normalize_together(
    features: Sequence[np.ndarray],
    mean: np.ndarray,
    std: np.ndarray,
    prior_frames: float,
    states: Sequence[NormState | None],
    memory_frames: int = 0,
) -> tuple[list[np.ndarray], list[NormState]]:
    """:func:`running_normalize` of several streams' next frames at once (``states[i]`` continues
    ``features[i]``, ``(frames_i, dims)``): one cumulative sum over all of them."""
    mean64, std64 = np.asarray(mean, dtype=np.float64), np.asarray(std, dtype=np.float64)
    prior: Sums = (float(prior_frames), prior_frames * mean64, prior_frames * (std64**2 + mean64**2))
    if memory_frames > 0:
        return _windowed_normalize(features, states, prior, memory_frames)
    begun = [prior if state is None else cast(Sums, state) for state in states]
    lengths = np.array([len(x) for x in features])
    ends = np.cumsum(lengths)
    x = np.concatenate([np.asarray(f, dtype=np.float64) for f in features])
    starts = np.repeat(ends - lengths, lengths)
    counts = np.repeat([count for count, _, _ in begun], lengths) + (np.arange(len(x)) - starts + 1)
    sums = _running_sums(x, lengths, np.stack([total for _, total, _ in begun]))
    sum_squares = _running_sums(x**2, lengths, np.stack([squares for _, _, squares in begun]))
    mu = sums / counts[:, None]
    sigma = np.sqrt(np.maximum(sum_squares / counts[:, None] - mu**2, 1e-4))
    out = ((x - mu) / sigma).astype(np.float32)
    last: list[NormState] = [
        state if not n else (float(counts[end - 1]), sums[end - 1], sum_squares[end - 1])
        for state, n, end in zip(begun, lengths.tolist(), ends.tolist())
    ]
    return [out[end - n : end] for n, end in zip(lengths.tolist(), ends.tolist())], last


def _running_sums(rows: np.ndarray, lengths: np.ndarray, initial: np.ndarray) -> np.ndarray:
    """Each stream's cumulative sums of its ``rows`` (the streams' rows one after another,
    ``lengths[i]`` of stream i) from its ``initial`` sums (``(streams, dims)``), all in one
    cumulative sum."""
    sums = np.cumsum(rows, axis=0)
    if len(lengths) > 1:  # each stream's sums from its own start
        before = (np.cumsum(lengths) - lengths).repeat(lengths) - 1
        sums -= np.where(before[:, None] >= 0, sums[np.maximum(before, 0)], 0.0)
    return sums + np.repeat(initial, lengths, axis=0)


def _windowed_normalize(
    features: Sequence[np.ndarray], states: Sequence[NormState | None], prior: Sums, memory: int
) -> tuple[list[np.ndarray], list[NormState]]:
    """:func:`running_normalize_together` with ``memory_frames`` = ``memory``. A stream's state is
    its last ``memory`` (or fewer) frames and their sums; the window's sums at each new frame
    are those plus the cumulative sum of the new frames less the frames leaving the window, for
    all the streams at once. The ``prior`` counts while no more than ``memory`` frames were heard."""
    begun = [_Window.empty(len(prior[1])) if state is None else cast(_Window, state) for state in states]
    new = [np.asarray(f, dtype=np.float64) for f in features]
    leaving = np.concatenate([window.leaving(frames, memory) for window, frames in zip(begun, new)])
    lengths = np.array([len(f) for f in new])
    x = np.concatenate(new)
    heard = np.concatenate([len(w.frames) + np.arange(n) for w, n in zip(begun, lengths.tolist())])
    sums = _running_sums(x - leaving, lengths, np.stack([w.total for w in begun]))
    sum_squares = _running_sums(x**2 - leaving**2, lengths, np.stack([w.squares for w in begun]))
    filling = (heard < memory)[:, np.newaxis]  # the window is not yet full: the prior still counts
    count = np.minimum(heard + 1, memory)[:, np.newaxis] + np.where(filling, prior[0], 0.0)
    mu = (sums + np.where(filling, prior[1], 0.0)) / count
    second = (sum_squares + np.where(filling, prior[2], 0.0)) / count
    out = ((x - mu) / np.sqrt(np.maximum(second - mu**2, 1e-4))).astype(np.float32)
    ends = np.cumsum(lengths).tolist()
    last: list[NormState] = [
        window if not n else window.after(frames, sums[end - 1], sum_squares[end - 1], memory)
        for window, frames, n, end in zip(begun, new, lengths.tolist(), ends)
    ]
    return [out[end - n : end] for n, end in zip(lengths.tolist(), ends)], last


@dataclass(frozen=True)
class _Window:
    """A stream's state in :func:`_windowed_normalize`: its last frames (at most the memory),
    ``buffer[start:stop]``, and their sum and sum of squares per dimension. The buffer has room
    for twice the memory: new frames are written after the old ones, and only when it is full
    are the frames kept copied to a new one, so a state shares its buffer with the states
    before it (a stream goes on from its newest state only)."""

    buffer: np.ndarray
    start: int
    stop: int
    total: np.ndarray
    squares: np.ndarray

    @classmethod
    def empty(cls, dims: int) -> _Window:
        return cls(np.zeros((0, dims)), 0, 0, np.zeros(dims), np.zeros(dims))

    @property
    def frames(self) -> np.ndarray:
        return self.buffer[self.start : self.stop]

    def leaving(self, new: np.ndarray, memory: int) -> np.ndarray:
        """The frame each of ``new`` pushes out of a window of ``memory`` frames (zeros before it is full)."""
        held = self.stop - self.start  # never more than the memory
        filling = min(len(new), memory - held)
        pushed_out = self.frames[: max(0, held + len(new) - memory)]
        return np.concatenate([np.zeros((filling, new.shape[1])), pushed_out, new[: max(0, len(new) - memory)]])

    def after(self, new: np.ndarray, total: np.ndarray, squares: np.ndarray, memory: int) -> _Window:
        """The state once ``new`` frames were heard, whose window sums are ``total`` and ``squares``."""
        if self.stop + len(new) <= len(self.buffer):
            self.buffer[self.stop : self.stop + len(new)] = new
            stop = self.stop + len(new)
            return _Window(self.buffer, max(self.start, stop - memory), stop, total, squares)
        kept = np.concatenate([self.frames, new])[-memory:]
        buffer = np.empty((2 * memory, new.shape[1]))
        buffer[: len(kept)] = kept
        return _Window(buffer, 0, len(kept), total, squares)


class SpectrumStream:
    """Power spectra of audio arriving in chunks, equal to :func:`power_spectrogram` of it all.

    :meth:`push` takes float samples at :data:`SAMPLE_RATE` Hz and returns the frames that
    became complete; :meth:`finish` pads the end as the offline call does and returns the rest.
    """

    def __init__(self) -> None:
        self._buffer = np.zeros(N_FFT // 2, dtype=np.float32)  # the leading pad
        self._consumed = 0  # samples of the padded signal dropped from the buffer's front
        self.frames = 0
        """Frames given so far."""
        self.samples = 0
        """Samples pushed so far."""

    def push(self, samples: np.ndarray) -> np.ndarray:
        return self.push_together([self], [samples])[0]

    @staticmethod
    def push_together(streams: Sequence[SpectrumStream], chunks: Sequence[np.ndarray]) -> list[np.ndarray]:
        """:meth:`push` of ``chunks[i]`` to ``streams[i]``, the new frames of all of them in one FFT."""
        frames = []
        for stream, samples in zip(streams, chunks):
            chunk = np.asarray(samples, dtype=np.float32).reshape(-1)
            stream.samples += len(chunk)
            stream._buffer = np.concatenate([stream._buffer, chunk])
            frames.append(stream._take(stream._complete_frames()))
        power = _windows_power(np.concatenate(frames))
        bounds = np.cumsum([0, *map(len, frames)]).tolist()
        return [power[a:b] for a, b in pairwise(bounds)]

    def finish(self) -> np.ndarray:
        total = self.samples // HOP + 1
        needed = (total - 1) * HOP + N_FFT - self._consumed
        self._buffer = np.pad(self._buffer, (0, max(0, needed - len(self._buffer))))
        return _windows_power(self._take(total))

    def _complete_frames(self) -> int:
        """Frames whose window lies inside the samples pushed so far (never more than the offline count)."""
        padded = self._consumed + len(self._buffer)
        return min(max(0, (padded - N_FFT) // HOP + 1), self.samples // HOP + 1)

    def _take(self, upto: int) -> np.ndarray:
        """``(n, N_FFT)``: the samples of the frames before ``upto`` not yet given; drops those no later frame needs."""
        n = max(0, upto - self.frames)
        start = self.frames * HOP - self._consumed
        frames = self._buffer[start + np.arange(n)[:, np.newaxis] * HOP + np.arange(N_FFT)]
        self.frames += n
        drop = self.frames * HOP - self._consumed
        self._buffer = self._buffer[drop:]
        self._consumed += drop
        return frames
