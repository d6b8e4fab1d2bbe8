"""Silero VAD v6's network on NumPy, many streams' windows at once.

The shipped ONNX file (``data/silero_vad_v6.onnx``, read here without ONNX: its weights are the
graph's initialisers) runs one stream's windows as the sequence of its LSTM, with one state, so
ONNX Runtime can only take the streams one call each. The same graph on NumPy takes every
stream's next windows in one call: the encoder (a 256-point STFT as a strided convolution, the
magnitude of bins 0–128 of its last four frames, four 3-tap convolutions with ReLU, strides 1,
2, 2, 1) for all windows at once, then the LSTM one step for every stream with a window at that
step, then the decoder (ReLU, a linear unit, sigmoid) for all. Its probabilities equal ONNX
Runtime's to float32 rounding (tested).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

import numpy as np

MODEL = Path(__file__).parent / "data" / "silero_vad_v6.onnx"
INPUT = 576
"""Samples a window's input has: :data:`~vispeech.frontends.vad.CONTEXT` before it, then the window."""
HIDDEN = 128
"""The LSTM's state size (``h`` and ``c``)."""
_PAD = 128  # reflected samples each side of a window's input before the STFT
_HOP = 128
_FFT = 256


class Silero:
    """The network's weights, and :meth:`probabilities` of windows of many streams at once."""

    def __init__(self, weights: dict[str, np.ndarray]) -> None:
        basis = weights["encoder.feature_extractor.forward_basis_buffer"][:, 0, :]  # (258, 256): real, imaginary
        self.basis = np.ascontiguousarray(basis.T)
        self.convs = [
            (
                np.ascontiguousarray(weights[f"encoder.conv_layers.{k}.weight"].transpose(2, 1, 0)).reshape(
                    -1, len(weights[f"encoder.conv_layers.{k}.bias"])
                ),
                weights[f"encoder.conv_layers.{k}.bias"],
            )
            for k in range(4)
        ]
        self.input_weights = np.ascontiguousarray(weights["onnx::LSTM_209"][0].T)  # gates i, o, f, c
        self.state_weights = np.ascontiguousarray(weights["onnx::LSTM_210"][0].T)
        bias = weights["onnx::LSTM_211"][0]
        self.bias = bias[: 4 * HIDDEN] + bias[4 * HIDDEN :]
        self.out_weights = weights["decoder.conv1d.weight"][0, :, 0]
        self.out_bias = float(weights["decoder.conv1d.bias"][0])

    def probabilities(
        self, inputs: Sequence[np.ndarray], states: Sequence[np.ndarray]
    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Speech probabilities of each stream's windows ``inputs[i]`` (``(n_i, INPUT)`` float32,
        in time order) from its state ``states[i]`` (``(2, HIDDEN)``: ``h``, ``c``), and each
        stream's state after them."""
        lengths = [len(x) for x in inputs]
        drive = self._encode(np.concatenate(inputs)) @ self.input_weights + self.bias
        firsts = np.cumsum([0, *lengths[:-1]])
        h = np.stack([state[0] for state in states])
        c = np.stack([state[1] for state in states])
        hidden = np.empty((len(drive), HIDDEN), np.float32)
        for step in range(max(lengths, default=0)):
            active = np.array([k for k, n in enumerate(lengths) if n > step])
            rows = firsts[active] + step
            gates = drive[rows] + h[active] @ self.state_weights
            i, o, f = (1.0 / (1.0 + np.exp(-gates[:, k * HIDDEN : (k + 1) * HIDDEN])) for k in range(3))
            c[active] = f * c[active] + i * np.tanh(gates[:, 3 * HIDDEN :])
            h[active] = o * np.tanh(c[active])
            hidden[rows] = h[active]
        logits = np.maximum(hidden, 0.0) @ self.out_weights + self.out_bias
        probabilities = 1.0 / (1.0 + np.exp(-logits))
        parts = [probabilities[a : a + n] for a, n in zip(firsts.tolist(), lengths)]
        return parts, [np.stack([h[k], c[k]]) for k in range(len(inputs))]

    def _encode(self, windows: np.ndarray) -> np.ndarray:
        """``(n, HIDDEN)``: the encoder's output for each window input."""
        n = len(windows)
        padded = np.concatenate([windows[:, _PAD:0:-1], windows, windows[:, -2 : -_PAD - 2 : -1]], axis=1)  # reflect
        spectra = padded[:, _FRAMES].reshape(4 * n, _FFT) @ self.basis
        half = self.basis.shape[1] // 2
        x = np.sqrt(spectra[:, :half] ** 2 + spectra[:, half:] ** 2).reshape(n, 4, half)
        for (weight, bias), stride in zip(self.convs, (1, 2, 2, 1)):
            x = _conv(x, weight, bias, stride)
        return x[:, 0, :]


_FRAMES = _HOP * np.arange(1, 5)[:, np.newaxis] + np.arange(_FFT)
"""The samples of the STFT's frames 1–4 in a padded window input (the graph drops frame 0)."""


def _conv(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, stride: int) -> np.ndarray:
    """A 3-tap convolution over the time axis of ``x`` (``(n, time, channels)``), padded by one
    frame of zeros each side, then ReLU: ``weight`` is ``(3 · channels, out)``, tap-major."""
    n, time, channels = x.shape
    padded = np.zeros((n, time + 2, channels), np.float32)
    padded[:, 1:-1] = x
    starts = np.arange(0, time, stride)
    taps = padded[:, starts[:, np.newaxis] + np.arange(3)].reshape(n * len(starts), 3 * channels)
    return np.maximum(taps @ weight + bias, 0.0).reshape(n, len(starts), len(bias))


@functools.cache
def network() -> Silero:
    """The shipped model's network (read once a process)."""
    return Silero(_initialisers(MODEL.read_bytes()))


def _initialisers(model: bytes) -> dict[str, np.ndarray]:
    """The float32 initialisers of an ONNX model file (ModelProto.graph.initializer, raw data)."""
    weights = {}
    for number, graph in _fields(model):
        if number != 7:  # ModelProto.graph
            continue
        for kind, tensor in _fields(graph):
            if kind != 5:  # GraphProto.initializer
                continue
            dims, name, raw, data_type = [], "", b"", 0
            for field, value in _fields(tensor):
                if field == 1:  # dims: one varint each, or packed
                    dims.extend([value] if isinstance(value, int) else _packed(value))
                elif field == 2:
                    data_type = value
                elif field == 8:
                    name = value.decode()
                elif field == 9:
                    raw = value
            if data_type == 1:  # FLOAT
                weights[name] = np.frombuffer(raw, "<f4").reshape(dims)
    return weights


def _fields(message: bytes):
    """``(field number, value)`` of a protocol buffer message: an int for a varint, bytes otherwise."""
    at = 0
    while at < len(message):
        key, at = _varint(message, at)
        wire = key & 7
        value: int | bytes
        if wire == 0:
            value, at = _varint(message, at)
        elif wire == 2:
            size, at = _varint(message, at)
            value, at = message[at : at + size], at + size
        else:  # fixed 64 or 32 bits
            size = 8 if wire == 1 else 4
            value, at = message[at : at + size], at + size
        yield key >> 3, value


def _packed(data: bytes) -> list[int]:
    values, at = [], 0
    while at < len(data):
        value, at = _varint(data, at)
        values.append(value)
    return values


def _varint(message: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = message[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, at
