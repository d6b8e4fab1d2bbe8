"""Audio networks run live: audio pushed in chunks, frames out as soon as they may be computed.

:class:`AudioStream` drives an :class:`~vispeech.models.networks.audio.AudioNetwork` from
audio chunks (log-mel features computed incrementally, or a speech encoder's states from an
:class:`EncoderStream`); :class:`EncoderStream` gives a speech encoder's hidden states as a
live stream has them, which networks trained with ``encoder_streamed`` also read offline.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import pairwise
from typing import TYPE_CHECKING

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.encoder import SpeechEncoder
from vispeech.frontends.features import SAMPLE_RATE, SpectrumStream
from vispeech.models.networks.kernels import AudioCNNStream
from vispeech.models.streams import ModelStream, ResampledFrames

if TYPE_CHECKING:
    from vispeech.frontends.whisper import WhisperEncoder
    from vispeech.models.networks.audio import AudioNetwork
    from vispeech.models.networks.audio_encoding import AudioEncoding


def speech_encoder(encoding: AudioEncoding) -> SpeechEncoder | WhisperEncoder:
    """The speech encoder an encoding of ``kind="encoder"`` reads (its folder, at its
    ``encoder_depth``), loaded once and shared."""
    if encoding.encoder is None:
        raise VispeechError(f"{encoding.kind} features come from no speech encoder")
    return SpeechEncoder.load(encoding.encoder, encoding.encoder_depth)


class AudioStream(ModelStream[np.ndarray]):
    """An audio network driven by audio chunks as they arrive (a microphone, a voice service).

    :meth:`push` takes float samples at :data:`~vispeech.frontends.features.SAMPLE_RATE` Hz
    (mono, in [-1, 1]) and returns ``(start_frame, frames)`` at the stream's ``fps``; network
    frame t is computed once the inputs up to ``t + lookahead`` are in: ``audio-cnn``
    incrementally (each layer keeps the rows its next outputs need, so every frame is computed
    once), and the frames equal :meth:`AudioNetwork.predict`'s on the whole audio; the
    encoder-decoder by re-running the network on the last ``context + lookahead`` frames;
    :meth:`finish` pads the end as the offline prediction does. :attr:`delay` is the audio
    (seconds) after a frame's time that the stream waits for. With encoder features the input
    rows come from re-encoded recent audio instead (see the module docstring), which makes the
    frames an approximation of the offline ones.
    """

    model: AudioNetwork

    def __init__(self, model: AudioNetwork, fps: float) -> None:
        super().__init__(model, "", fps)
        self.delay = model.delay
        self.lookahead = math.ceil(self.delay * self.fps)
        self._samples = 0  # pushed so far
        self._encoder: EncoderStream | None
        if model.encoding_.kind == "encoder":
            self._encoder = EncoderStream(speech_encoder(model.encoding_), model.fps_, model.get_params())
        else:
            self._encoder = None
            self._spectra = SpectrumStream()
        self._unheard: list[np.ndarray] = []  # audio fed whose features are not computed yet
        self._norm_state: object = None  # AudioEncoding.normalise's running state
        self._normalised = np.zeros((0, model.encoding_.dims), np.float32)  # feature frames not yet stacked
        self._inputs: list[np.ndarray] = []  # network input rows from row _first_input on
        self._first_input = 0
        self._frames = ResampledFrames(model.fps_, self.fps)
        kernel = model.kernel
        # a convolution network runs incrementally, each frame once; others re-run a recent window
        self._incremental: AudioCNNStream | None = (
            kernel.stream(model.encoding_.size) if hasattr(kernel, "stream") else None
        )

    @property
    def sample_rate(self) -> int:
        """The rate :meth:`push` takes (Hz)."""
        return SAMPLE_RATE

    def push(self, samples: np.ndarray) -> tuple[int, np.ndarray]:
        self.feed(samples)
        return self.collect()

    def feed(self, samples: np.ndarray) -> None:
        """Add samples (their features and network inputs); the network frames they make
        computable are left to :meth:`advance_together` (or :meth:`collect`)."""
        if self.closed:
            raise VispeechError("this audio stream has ended")
        chunk = np.asarray(samples, dtype=np.float32).reshape(-1)
        if not np.all(np.isfinite(chunk)):
            raise VispeechError("audio chunk has non-finite samples")
        chunk = np.clip(chunk, -1.0, 1.0)
        self._samples += len(chunk)
        self.end = self._samples / SAMPLE_RATE
        if self._encoder is None:
            self._unheard.append(chunk)
        else:
            self._add_hidden(chunk, final=False)

    def collect(self) -> tuple[int, np.ndarray]:
        if self._unheard or self._inputs:  # else advanced already (advance_together): nothing to compute
            self.advance_together([self])
        n_total = math.ceil(self.end * self.fps - 1e-9)
        return self._give(min(self._frames.ready(), n_total))

    @classmethod
    def advance_together(cls, streams: Sequence[AudioStream]) -> None:
        """Compute the network frames the audio fed to ``streams`` made computable: the spectra
        of all of them in one FFT, the features of the streams of one network in one filter-bank
        product and normalisation, the incremental streams of one network together (each layer
        one matrix product for the new frames of all of them), the others one by one."""
        _featurise([stream for stream in streams if stream._unheard])
        groups: dict[int, list[AudioStream]] = {}
        for stream in streams:
            if stream._incremental is None:
                stream._advance(stream._first_input + len(stream._inputs) - stream.model.kernel_ahead, final=False)
            elif stream._inputs:
                groups.setdefault(id(stream._incremental.kernel), []).append(stream)
        for group in groups.values():
            _advance_incremental(group, final=False)

    def finish(self) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this audio stream has ended")
        if self._encoder is None:
            _featurise([self], final=True)
        else:
            self._add_hidden(np.zeros(0, dtype=np.float32), final=True)
        self.close()
        if self._samples == 0:
            return self._empty()
        self._advance(self._n_model_frames(), final=True)
        return self._give(max(1, math.ceil(self.end * self.fps - 1e-9)))

    def _n_model_frames(self) -> int:
        return max(1, math.ceil(self.end * self.model.fps_ - 1e-9))

    def _add_normalised(self, normalised: np.ndarray, final: bool = False) -> None:
        """Stack the next normalised feature frames into network input rows; with ``final``, as
        offline, the last feature frame repeated to fill the network frames the audio covers."""
        encoding = self.model.encoding_
        stack = encoding.stack
        rows = np.concatenate([self._normalised, normalised]) if len(self._normalised) else normalised
        whole = len(rows) // stack
        self._inputs.extend(rows[: whole * stack].reshape(whole, encoding.size))
        self._normalised = rows[whole * stack :]
        if final:
            n = self._n_model_frames() if self._samples else 0
            tail = list(self._normalised) or ([self._inputs[-1][-encoding.dims :]] if self._inputs else [])
            while self._first_input + len(self._inputs) < n and tail:
                self._inputs.append(np.concatenate((tail + [tail[-1]] * stack)[:stack]))
                tail = [tail[-1]]

    def _add_hidden(self, chunk: np.ndarray, final: bool) -> None:
        """Add the encoder input rows of the hidden states the :class:`EncoderStream` gives."""
        assert self._encoder is not None  # called only for encoder features
        states = self._encoder.push(chunk, final)
        if states.shape[1]:
            self._inputs.extend(self.model.encoding_.encode(states, states.shape[1]))

    def _advance(self, upto: int, final: bool) -> None:
        """Compute network frames up to (not including) ``upto`` (an incremental network: all it can)."""
        model = self.model
        if self._incremental is not None:
            _advance_incremental([self], final)
            return
        if not final:
            upto = min(upto, self._n_model_frames())
        start = self._frames.computed
        if upto <= start:
            return
        window_start = max(self._first_input, start - model.context)
        rows = np.stack(self._inputs[window_start - self._first_input :])
        if final:
            rows = rows[: upto - window_start]
        out = model._denormalise(model.kernel.forward(rows))
        for row in out[start - window_start : upto - window_start]:
            self._frames.add(row)
        keep_from = max(self._first_input, self._frames.computed - model.context)
        del self._inputs[: keep_from - self._first_input]
        self._first_input = keep_from

    def _give(self, upto: int) -> tuple[int, np.ndarray]:
        if upto <= self.emitted or not self._frames.computed:
            return self._empty()
        start, self.emitted = self.emitted, upto
        return start, self._frames.give(start, upto)


def _featurise(streams: Sequence[AudioStream], final: bool = False) -> None:
    """The network input rows of the audio fed to ``streams`` (of spectral features): the spectra
    of all of them in one FFT, the features and their normalisation one call for the streams of
    each network; with ``final``, up to the audio's end."""
    if not streams:
        return
    chunks = [np.concatenate(s._unheard or [np.zeros(0, np.float32)]) for s in streams]
    for stream in streams:
        stream._unheard = []
    powers = SpectrumStream.push_together([s._spectra for s in streams], chunks)
    if final:
        powers = [np.concatenate([power, s._spectra.finish()]) for power, s in zip(powers, streams)]
    groups: dict[int, list[int]] = {}
    for k, stream in enumerate(streams):
        groups.setdefault(id(stream.model), []).append(k)
    for members in groups.values():
        encoding = streams[members[0]].model.encoding_
        features = encoding.features(np.concatenate([powers[k] for k in members]))
        bounds = np.cumsum([0, *(len(powers[k]) for k in members)]).tolist()
        parts = [features[a:b] for a, b in pairwise(bounds)]
        normalised, states = encoding.normalise_together(parts, [streams[k]._norm_state for k in members])
        for k, rows, state in zip(members, normalised, states):
            streams[k]._norm_state = state
            streams[k]._add_normalised(rows, final)


def _advance_incremental(streams: Sequence[AudioStream], final: bool) -> None:
    """Run the inputs waiting in ``streams`` (incremental, of one network) through the network
    together; with ``final``, each stream's last frames as if its input ended there."""
    model = streams[0].model
    pending = [s._inputs[: s._n_model_frames() - s._first_input] if final else s._inputs for s in streams]
    waiting = [row for p in pending for row in p]
    stacked = np.stack(waiting) if waiting else np.zeros((0, model.encoding_.size), np.float32)
    rows = [stacked[a:b] for a, b in pairwise(np.cumsum([0, *map(len, pending)]).tolist())]
    outs = AudioCNNStream.push_together([s._incremental for s in streams if s._incremental is not None], rows, final)
    denormalised = iter(model._denormalise(np.concatenate(outs)))
    for stream, out in zip(streams, outs):
        for _ in range(len(out)):
            stream._frames.add(next(denormalised))
        stream._first_input += len(stream._inputs)
        stream._inputs = []


class EncoderStream:
    """A speech encoder's hidden states of audio pushed in chunks, as a live stream has them.

    Each time the audio reaches a multiple of ``encoder_step`` seconds (and at the end) it
    re-encodes the audio from ``encoder_context`` seconds before the first frame it has not
    given up to there, and gives the frames that ``encoder_ahead`` seconds of that audio
    follow: a frame's states come from a window that ends ``encoder_ahead`` to ``encoder_ahead
    + encoder_step`` seconds after it (``params``: an audio network's). The windows do not
    depend on how the audio is chunked. :meth:`push` takes float samples at 16 kHz and returns
    the new frames' ``(layers, frames, width)`` states at ``fps``; ``final`` gives the rest of
    ``ceil(duration · fps)`` frames. An audio network with ``encoder_streamed`` trains and
    predicts on exactly these states, so its stream equals its offline output.
    """

    def __init__(self, encoder, fps: float, params: dict) -> None:
        self.encoder = encoder
        self._hop = round(SAMPLE_RATE / fps)
        self._ahead = round(params["encoder_ahead"] * SAMPLE_RATE)
        self._step = max(self._hop, round(params["encoder_step"] * fps) * self._hop)  # samples between encodings
        self._context = round(params["encoder_context"] * fps)
        self._audio = np.zeros(0, dtype=np.float32)  # the samples from frame _audio_start on
        self._audio_start = 0
        self._samples = 0
        self._encoded_to = 0  # samples heard at the last encoding
        self._given = 0

    def push(self, chunk: np.ndarray, final: bool = False) -> np.ndarray:
        chunk = np.asarray(chunk, dtype=np.float32).reshape(-1)
        self._audio = np.concatenate([self._audio, chunk])
        self._samples += len(chunk)
        parts = []
        while self._encoded_to + self._step <= self._samples:
            self._encoded_to += self._step
            upto = max(0, (self._encoded_to - self._ahead) // self._hop + 1)
            parts.append(self._encode(min(upto, math.ceil(self._encoded_to / self._hop - 1e-9)), self._encoded_to))
        if final:
            parts.append(self._encode(math.ceil(self._samples / self._hop - 1e-9), self._samples))
        parts = [p for p in parts if p.shape[1]]
        if not parts:
            return np.zeros((self.encoder.layers, 0, self.encoder.width), dtype=np.float32)
        return np.concatenate(parts, axis=1)

    def _encode(self, upto: int, heard: int) -> np.ndarray:
        """States of frames ``_given .. upto`` from the audio up to sample ``heard``."""
        if upto <= self._given:
            return np.zeros((self.encoder.layers, 0, self.encoder.width), dtype=np.float32)
        start = max(self._audio_start, self._given - self._context)
        audio = self._audio[(start - self._audio_start) * self._hop : heard - self._audio_start * self._hop]
        states = self.encoder.hidden_states(AudioClip.from_array(audio, SAMPLE_RATE))
        index = np.minimum(np.arange(self._given - start, upto - start), states.shape[1] - 1)
        self._given = upto
        keep = max(self._audio_start, upto - self._context)
        self._audio = self._audio[(keep - self._audio_start) * self._hop :]
        self._audio_start = keep
        return states[:, index]
