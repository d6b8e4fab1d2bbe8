"""NumPy forward passes of the trained networks: what prediction runs on, without torch.

The weights are the torch modules' state dicts (``vispeech.models.networks.modules``) as
NumPy arrays; each kernel computes what its module computes in float64 (to 1e-7 or better).

:class:`RecurrentKernel` (Beskow's time-delay networks) splits the work in two:

- the input window term ``conv_t = b + Σ_k W_k x_{t-back+k}``. Inputs are piecewise constant
  (one row per phone, and a different one on a phone's first frame), so with
  ``G_r[m] = Σ_{k<m} W_k v_r`` for each run r of equal rows v_r,
  ``conv_t = G_{run(t+K-1)}[K] + Σ_{boundaries b in (t, t+K)} (G_r − G_{r+1})[b − t]``:
  a few slice additions per phone instead of a K-frame product per frame. ``G`` of a row is
  cached (phone rows recur across utterances);
- the recurrence ``h_t = tanh(conv_t + Σ_d R_d h_{t-d})``, one small matrix-vector product
  per frame and network, in float32 (the weights' own precision) on a state buffer laid out
  oldest first, so the delayed states are one contiguous slice; several utterances step
  together (:meth:`RecurrentKernel.forward_many`), each with the bits it gets alone.

:class:`WindowKernel` (the sliding-window networks) is a plain MLP over the flattened windows
with the outputs' overlap average.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import pairwise
from typing import TypedDict

import numpy as np

from vispeech.turns import give_turn

TURN_FRAMES = 1000
"""A recurrent layer gives others a turn (:func:`vispeech.turns.give_turn`) every so many frames
of a long input (about 20 ms of work)."""
_CACHE_ROWS = 1024
"""Input rows whose window terms a :class:`RecurrentKernel` keeps (about 20 KB each for the shipped networks)."""


class RecurrentKernel:
    """Grouped recurrent time-delay networks (``GroupedNetworks`` of ``RecurrentTimeDelayNet``).

    ``columns[i]`` are the output columns network i predicts; ``back`` and ``ahead`` the
    input window's frames before and after the current one; ``events`` the input columns that
    are set on single frames (a phone's first): the window terms of a row are cached without
    them and their own added, so the cache holds about one row per phone.
    """

    def __init__(
        self,
        weights: Mapping[str, np.ndarray],
        columns: Sequence[Sequence[int]],
        back: int,
        ahead: int,
        events: Sequence[int] = (),
    ):
        self.back = back
        self.window = back + ahead + 1
        self.order = np.argsort([c for group in columns for c in group])
        self.nets = []
        cumulative = []
        for i in range(len(columns)):
            conv = np.asarray(weights[f"nets.{i}.input.weight"], dtype=np.float64)  # hidden, inputs, window
            hidden, n_inputs, window = conv.shape
            if window != self.window:
                raise ValueError(f"network {i} has an input window of {window} frames, expected {self.window}")
            recurrent = np.asarray(weights[f"nets.{i}.recurrent.weight"], dtype=np.float64)  # hidden, delays*hidden
            delays = recurrent.shape[1] // hidden
            oldest_first = recurrent.reshape(hidden, delays, hidden)[:, ::-1, :].reshape(hidden, delays * hidden)
            per_frame = np.transpose(conv, (2, 1, 0))  # window, inputs, hidden
            cumulative.append(np.concatenate([np.zeros((1, n_inputs, hidden)), np.cumsum(per_frame, axis=0)]))
            self.nets.append(
                {
                    "hidden": hidden,
                    "delays": delays,
                    "bias": np.asarray(weights[f"nets.{i}.input.bias"], dtype=np.float64),
                    "conv": np.ascontiguousarray(per_frame.reshape(window * n_inputs, hidden)),
                    "recurrent": np.ascontiguousarray(oldest_first, dtype=np.float32),
                    "recurrent_and_drive": np.concatenate([oldest_first, np.eye(hidden)], axis=1).astype(np.float32),
                    "out_weight": np.asarray(weights[f"nets.{i}.output.weight"], dtype=np.float64).T,
                    "out_bias": np.asarray(weights[f"nets.{i}.output.bias"], dtype=np.float64),
                }
            )
        self.hidden = sum(net["hidden"] for net in self.nets)
        # C[f, m, :] = Σ_{k<m} W_k[f, :] over every network's hidden units, as inputs × (window+1)·hidden
        self._cumulative = np.concatenate(cumulative, axis=2).transpose(1, 0, 2).reshape(n_inputs, -1)
        self._events = np.asarray(events, dtype=np.intp)
        self._event_terms = np.ascontiguousarray(
            self._cumulative[self._events].reshape(len(self._events), self.window + 1, self.hidden)[:, ::-1],
            dtype=np.float32,
        )
        self._bias = np.concatenate([net["bias"] for net in self.nets]).astype(np.float32)
        self._rows: dict[bytes, np.ndarray] = {}

    # -- offline ---------------------------------------------------------------------------

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        """Outputs (frames × outputs, float64) for one utterance's input rows (frames × inputs)."""
        return self.forward_many([inputs])[0]

    def forward_many(self, inputs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """:meth:`forward` of several utterances' input rows, bit for bit: one :meth:`window_terms`
        over all of them (each padded with copies of its end rows: no window reaches another),
        then the recurrence stepping them all together."""
        x = [np.asarray(rows) for rows in inputs]
        ahead = self.window - 1 - self.back
        padded = [np.concatenate([r[:1].repeat(self.back, 0), r, r[-1:].repeat(ahead, 0)]) for r in x]
        starts = np.cumsum([0] + [len(p) for p in padded])[:-1] + self.back
        drive = self.window_terms(np.concatenate(padded)) if x else np.zeros((0, self.hidden), np.float32)
        outputs = []
        for states in self._recur([drive[start : start + len(r)] for start, r in zip(starts, x)]):
            parts = [h.astype(np.float64) @ net["out_weight"] + net["out_bias"] for net, h in zip(self.nets, states)]
            outputs.append(np.concatenate(parts, axis=1)[:, self.order])
        return outputs

    def window_terms(self, x: np.ndarray) -> np.ndarray:
        """``conv_t`` (the input window's drive, bias included) of every frame of the input rows
        ``x`` (frames × all hidden units, float32), the first and last row repeated beyond the ends."""
        n, k = len(x), self.window
        change = np.flatnonzero((x[1:] != x[:-1]).any(axis=1)) + 1
        rows = x[np.concatenate(([0], change))]
        base = self._base_terms(rows)  # per run: G[K - j] at row j, without the event columns
        events: list[list[tuple[int, float]]] = [[] for _ in range(len(rows))]
        set_rows, set_events = np.nonzero(rows[:, self._events])
        for r, e, weight in zip(
            set_rows.tolist(), set_events.tolist(), rows[set_rows, self._events[set_events]].tolist()
        ):
            events[r].append((e, weight))
        ends = self.back + change  # boundaries between runs, in padded frames
        # the run holding each window's last frame t + k - 1 contributes G[K]
        heads = np.stack([g[0] for g in base])
        for r, run_events in enumerate(events):
            for e, weight in run_events:
                heads[r] += self._event_terms[e, 0] if weight == 1.0 else weight * self._event_terms[e, 0]
        out = heads[np.searchsorted(ends, np.arange(k - 1, n + k - 1), side="right")]
        add, subtract = np.add, np.subtract
        for r, b in enumerate(ends.tolist()):  # boundary b between runs r and r+1 is felt by frames b-k+1 .. b-1
            lo, hi = max(b - k + 1, 0), min(b - 1, n - 1)
            if lo > hi:
                continue
            rows_at = slice(k - b + lo, k - b + hi + 1)  # (G_r − G_{r+1})[b − t] for t = lo .. hi
            view = out[lo : hi + 1]
            if base[r] is not base[r + 1]:  # a phone's onset and the rest of it share their base terms
                add(view, base[r][rows_at], out=view)
                subtract(view, base[r + 1][rows_at], out=view)
            for e, weight in events[r]:
                add(
                    view,
                    self._event_terms[e, rows_at] if weight == 1.0 else weight * self._event_terms[e, rows_at],
                    out=view,
                )
            for e, weight in events[r + 1]:
                subtract(
                    view,
                    self._event_terms[e, rows_at] if weight == 1.0 else weight * self._event_terms[e, rows_at],
                    out=view,
                )
        out += self._bias
        return out

    def _base_terms(self, rows: np.ndarray) -> list[np.ndarray]:
        """``G`` of each row without its event columns, reversed (row j holds ``G[K - j]``),
        float32: from the cache (the same array for the same row) or computed."""
        base = rows.copy()
        base[:, self._events] = 0
        keys = [row.tobytes() for row in base]
        cache = self._rows
        missing = list(dict.fromkeys(key for key in keys if key not in cache))
        if missing:
            if len(cache) + len(missing) > _CACHE_ROWS:
                cache.clear()
            fresh = np.frombuffer(b"".join(missing), dtype=rows.dtype).reshape(len(missing), -1).astype(np.float64)
            # row by row over its set columns: a row's terms never depend on the rows computed with it
            computed = np.stack([row[row != 0] @ self._cumulative[row != 0] for row in fresh])
            computed = computed.reshape(len(missing), self.window + 1, -1)
            cache.update(zip(missing, np.ascontiguousarray(computed[:, ::-1], dtype=np.float32)))
        return [cache[key] for key in keys]

    def _recur(self, drives: Sequence[np.ndarray]) -> list[list[np.ndarray]]:
        """Per utterance, the hidden states (frames × hidden, float32) of every network for its
        window terms. Row ``delays + t`` of an utterance's state buffer holds ``conv_t`` until
        ``h_t`` replaces it, so one product with ``[R | I]`` gives ``conv_t + Σ_d R_d h_{t-d}``: a
        step is one stacked matrix-vector product over the utterances still running, longest
        first (for each the BLAS call it gets alone: the same bits), and a tanh."""
        order = sorted(range(len(drives)), key=lambda i: -len(drives[i]))
        lengths, n = [len(drives[i]) for i in order], max(map(len, drives), default=0)
        running = np.searchsorted(-np.array(lengths), -np.arange(n), side="left").tolist()  # utterances past t
        states: list[list[np.ndarray]] = [[] for _ in drives]
        start = 0
        for net in self.nets:
            hidden, delays, matrix = net["hidden"], net["delays"], net["recurrent_and_drive"]
            buffer = np.zeros((len(order), n + delays, hidden), dtype=np.float32)  # oldest first: row delays + t is h_t
            for b, i in enumerate(order):
                buffer[b, delays : delays + lengths[b]] = drives[i][:, start : start + hidden]
            item = buffer.itemsize  # each utterance's window of states at step t: (delays + 1) rows from row t
            windows = np.lib.stride_tricks.as_strided(
                buffer, (n, len(order), (delays + 1) * hidden, 1), (hidden * item, buffer.strides[0], item, item)
            )
            step = np.empty((len(order), hidden, 1), dtype=np.float32)
            for t, active in enumerate(running):
                if not t % TURN_FRAMES:
                    give_turn()
                np.matmul(matrix, windows[t, :active], out=step[:active])
                np.tanh(step[:active, :, 0], out=buffer[:active, delays + t])
            for b, i in enumerate(order):
                states[i].append(buffer[b, delays : delays + lengths[b]])
            start += hidden
        return states

    # -- one frame at a time ---------------------------------------------------------------

    def initial_state(self) -> list[np.ndarray]:
        """Hidden states before the first frame, one (delays × hidden) buffer per network, oldest first."""
        return [np.zeros((net["delays"], net["hidden"]), dtype=np.float32) for net in self.nets]

    def advance(self, drive: np.ndarray, states: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
        """The outputs (streams × outputs) of one frame of each of several streams, from the frame's
        drive (streams × all hidden units: a row of :meth:`window_terms` each) and their states
        before it, stacked (per network: streams × delays × hidden; :meth:`initial_state` is one
        stream's). Several streams cost one product per network instead of one each."""
        outputs, new_states, start = [], [], 0
        for net, past in zip(self.nets, states):
            hidden = net["hidden"]
            h = np.tanh(past.reshape(len(past), -1) @ net["recurrent"].T + drive[:, start : start + hidden])
            start += hidden
            new_states.append(np.concatenate([past[:, 1:], h[:, None]], axis=1))
            outputs.append(h.astype(np.float64) @ net["out_weight"] + net["out_bias"])
        return np.concatenate(outputs, axis=1)[:, self.order], new_states


class WindowKernel:
    """A sliding-window MLP (``WindowMLP``): linear layers with ``activation`` between them."""

    def __init__(self, weights: Mapping[str, np.ndarray], input_window: int, output_window: int, activation: str):
        layers = sorted({int(key.split(".")[1]) for key in weights if key.startswith("layers.")})
        self.layers = [
            (
                np.asarray(weights[f"layers.{i}.weight"], dtype=np.float64).T,
                np.asarray(weights[f"layers.{i}.bias"], dtype=np.float64),
            )
            for i in layers
        ]
        self.input_window, self.output_window = input_window, output_window
        self.activation = activation

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        """Outputs (frames × outputs) for one utterance's input rows: every window, overlap-averaged."""
        windows = padded_windows(np.asarray(inputs, dtype=np.float64), self.input_window, self.output_window)
        h = windows.reshape(len(windows), -1)
        for i, (weight, bias) in enumerate(self.layers):
            h = h @ weight + bias
            if i < len(self.layers) - 1:
                h = np.tanh(h) if self.activation == "tanh" else np.where(h > 0, h, 0.1 * h)
        return overlap_average(h.reshape(len(h), self.output_window, -1), len(inputs))


def padded_windows(inputs: np.ndarray, input_window: int, output_window: int) -> np.ndarray:
    """The sliding windows (windows × input_window × features) of a sliding-window model: the
    rows padded at both ends with ``(Kx + Ky) / 2 − 1`` copies of the first and last, so that
    every frame lies in ``output_window`` windows' predictions."""
    pad = (input_window + output_window) // 2 - 1
    padded = np.pad(inputs, ((pad, pad), (0, 0)), mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, input_window, axis=0).transpose(0, 2, 1)


def overlap_average(out: np.ndarray, n: int) -> np.ndarray:
    """Frames (n × outputs) from the windows' predictions (windows × Ky × outputs): window w
    predicts frames w − Ky + 1 .. w, and each frame is the mean of its Ky predictions."""
    ky = out.shape[1]
    total = np.zeros((len(out) + ky - 1, out.shape[2]))
    for k in range(ky):
        total[k : k + len(out)] += out[:, k]
    return total[ky - 1 : ky - 1 + n] / ky


class _ConvLayer(TypedDict):
    """One layer of a :class:`ConvStackKernel`: frames (behind, ahead), weights, layer-norm gain and shift."""

    pad: tuple[int, int]
    weight: np.ndarray
    bias: np.ndarray
    gain: np.ndarray
    shift: np.ndarray


class ConvStackKernel:
    """The NumPy forward pass of ``ConvStack`` (1-D convolutions, ReLU, per-frame layer norm)
    with weights under ``prefix``; ``pads[i]`` = frames (behind, ahead) of layer i."""

    def __init__(self, weights: Mapping[str, np.ndarray], prefix: str, pads: Sequence[tuple[int, int]]):
        self.layers: list[_ConvLayer] = []
        for i, pad in enumerate(pads):
            conv = np.asarray(weights[f"{prefix}.convs.{i}.weight"], dtype=np.float32)  # out, in, kernel
            if conv.shape[2] != pad[0] + pad[1] + 1:
                raise ValueError(f"layer {i} has a kernel of {conv.shape[2]} frames, expected {sum(pad) + 1}")
            self.layers.append(
                {
                    "pad": pad,
                    "weight": np.ascontiguousarray(conv.transpose(2, 1, 0)),  # kernel, in, out
                    "bias": np.asarray(weights[f"{prefix}.convs.{i}.bias"], dtype=np.float32),
                    "gain": np.asarray(weights[f"{prefix}.norms.{i}.norm.weight"], dtype=np.float32),
                    "shift": np.asarray(weights[f"{prefix}.norms.{i}.norm.bias"], dtype=np.float32),
                }
            )
        self.behind = sum(layer["pad"][0] for layer in self.layers)
        """Frames of input before frame t that frame t's output depends on."""
        self.ahead = sum(layer["pad"][1] for layer in self.layers)
        """Frames of input after frame t that frame t's output depends on."""

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        """``(frames, inputs)`` to ``(frames, channels)``, zero-padded at both ends as in training."""
        h = np.asarray(inputs, dtype=np.float32)
        for layer in self.layers:
            give_turn()
            behind, ahead = layer["pad"]
            h = _conv_layer(layer, np.pad(h, ((behind, ahead), (0, 0))))
        return h


class ConvStackStream:
    """A :class:`ConvStackKernel` run incrementally: each layer keeps the input rows its next
    outputs still need, so every frame is computed once; the outputs equal
    :meth:`ConvStackKernel.forward` of all the rows given."""

    def __init__(self, kernel: ConvStackKernel, n_inputs: int):
        self.kernel = kernel
        widths = [n_inputs] + [len(layer["bias"]) for layer in kernel.layers[:-1]]
        self._buffers = [np.zeros((layer["pad"][0], w), dtype=np.float32) for layer, w in zip(kernel.layers, widths)]

    def push(self, rows: np.ndarray, final: bool = False) -> np.ndarray:
        """The output frames that ``rows`` (the next input frames) make computable; with
        ``final``, the rest, as if the input ended after ``rows``."""
        return self.push_together([self], [rows], final)[0]

    @staticmethod
    def push_together(
        streams: Sequence[ConvStackStream], rows: Sequence[np.ndarray], final: bool = False
    ) -> list[np.ndarray]:
        """:meth:`push` of ``rows[i]`` to ``streams[i]`` (all of one kernel), each layer's
        products taken once for the new frames of all of them (their windows' rows gathered):
        their outputs, in order."""
        hs = [np.asarray(r, dtype=np.float32) for r in rows]
        for i, layer in enumerate(streams[0].kernel.layers):
            behind, ahead = layer["pad"]
            tail = [np.zeros((ahead, hs[0].shape[1]), np.float32)] if final else []  # the end's padding
            extra = ahead if final else 0
            buffers = np.concatenate(
                [piece for stream, h in zip(streams, hs) for piece in (stream._buffers[i], h, *tail)]
            )
            lengths = [len(stream._buffers[i]) + len(h) + extra for stream, h in zip(streams, hs)]
            counts = [max(0, n - behind - ahead) for n in lengths]
            if not sum(counts):
                out = np.zeros((0, len(layer["bias"])), np.float32)
            elif len(streams) == 1:  # its windows are every whole one
                out = _conv_layer(layer, buffers)
            else:
                out = _conv_layer(layer, buffers, _window_starts(lengths, counts))
            for stream, n, end, length in zip(streams, counts, np.cumsum(lengths).tolist(), lengths):
                stream._buffers[i] = buffers[end - length + n : end] if not final else buffers[:0]
            hs = [out[a:b] for a, b in pairwise(np.cumsum([0, *counts]).tolist())]
        return hs


def _window_starts(lengths: Sequence[int], counts: Sequence[int]) -> np.ndarray:
    """Where the first ``counts[i]`` windows of each of several buffers (of ``lengths[i]`` rows,
    stacked one after another) begin in the rows stacked, buffer after buffer."""
    offsets = np.cumsum(lengths) - lengths  # where each buffer begins in the rows stacked
    before = np.cumsum(counts) - counts  # windows of the buffers before
    return np.arange(sum(counts)) + np.repeat(offsets - before, counts)


def _conv_layer(layer: _ConvLayer, rows: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
    """One convolution, ReLU and per-frame layer norm over the windows of already padded input
    ``rows`` that begin at ``starts`` (default: every whole window)."""
    n = len(rows) - len(layer["weight"]) + 1 if starts is None else len(starts)
    out = np.broadcast_to(layer["bias"], (n, len(layer["bias"]))).copy()
    for k, weight in enumerate(layer["weight"]):
        out += (rows[k : k + n] if starts is None else rows[starts + k]) @ weight
    np.maximum(out, 0.0, out=out)
    mean = out.mean(axis=1, keepdims=True)
    var = out.var(axis=1, keepdims=True)
    return (out - mean) / np.sqrt(var + 1e-5) * layer["gain"] + layer["shift"]


class LayerFusionKernel:
    """The NumPy forward pass of ``LayerFusion``: ``(frames, layers · width)`` encoder hidden
    states (layer-major) to ``(frames, width)``, weighted by the softmax of the saved logits."""

    def __init__(self, weights: Mapping[str, np.ndarray]):
        logits = np.asarray(weights["fusion.logits"], dtype=np.float64)
        self.weights = np.exp(logits - logits.max()) / np.exp(logits - logits.max()).sum()
        """The layers' weights (summing to 1)."""

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        x = np.asarray(inputs, dtype=np.float32)
        return np.einsum("tlw,l->tw", x.reshape(len(x), len(self.weights), -1), self.weights.astype(np.float32))


def _fusion(weights: Mapping[str, np.ndarray], fusion_layers: int) -> LayerFusionKernel | None:
    """The fusion in front of a network reading ``fusion_layers`` encoder hidden states (none when 0)."""
    if not fusion_layers:
        return None
    fusion = LayerFusionKernel(weights)
    if len(fusion.weights) != fusion_layers:
        raise ValueError(f"the fusion weighs {len(fusion.weights)} layers, expected {fusion_layers}")
    return fusion


def _phone_head(weights: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """The CTC head's weight (transposed) and bias, or ``None`` for a network trained without one."""
    if "ctc.weight" not in weights:
        return None
    return np.asarray(weights["ctc.weight"], dtype=np.float32).T, np.asarray(weights["ctc.bias"], dtype=np.float32)


def _posteriors(head: tuple[np.ndarray, np.ndarray] | None, hidden: np.ndarray) -> np.ndarray | None:
    """``(frames, phones + 1)`` phone posteriors (column 0: CTC's blank) of ``hidden``; ``None`` without a head."""
    if head is None:
        return None
    logits = (hidden @ head[0] + head[1]).astype(np.float64)
    e = np.exp(logits - logits.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


class AudioCNNKernel:
    """The NumPy forward pass of ``AudioCNN`` (its forward GRU when it has one), with its CTC
    head's phone posteriors when it has one."""

    def __init__(self, weights: Mapping[str, np.ndarray], pads: Sequence[tuple[int, int]], fusion_layers: int = 0):
        self.fusion = _fusion(weights, fusion_layers)
        self.encoder = ConvStackKernel(weights, "encoder", pads)
        self.gru = _gru_weights(weights, "gru.{}_l0") if "gru.weight_ih_l0" in weights else None
        self.out_weight = np.asarray(weights["output.weight"], dtype=np.float32).T
        self.out_bias = np.asarray(weights["output.bias"], dtype=np.float32)
        self.phone_head = _phone_head(weights)

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        return self.forward_with_phones(inputs)[0]

    def forward_with_phones(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The outputs and the phone posteriors (``None`` without a CTC head) of ``inputs``."""
        h = self.encoder.forward(inputs if self.fusion is None else self.fusion.forward(inputs))
        if self.gru is not None:
            h = _gru(h, *self.gru)
        return self._output(h), _posteriors(self.phone_head, h)

    def stream(self, n_inputs: int) -> AudioCNNStream:
        """An incremental forward pass over input rows of ``n_inputs`` values (:class:`AudioCNNStream`)."""
        width = n_inputs if self.fusion is None else n_inputs // len(self.fusion.weights)
        return AudioCNNStream(self, ConvStackStream(self.encoder, width), width)

    def _output(self, hidden: np.ndarray) -> np.ndarray:
        return (hidden @ self.out_weight + self.out_bias).astype(np.float64)


class AudioCNNStream:
    """:class:`AudioCNNKernel` frame by frame: ``push(rows, final)`` returns the outputs the
    rows made computable, equal to :meth:`AudioCNNKernel.forward` of all rows (the GRU's
    state carried from push to push)."""

    def __init__(self, kernel: AudioCNNKernel, convs: ConvStackStream, width: int):
        self.kernel, self.convs, self.width = kernel, convs, width
        self._state = None if kernel.gru is None else np.zeros(len(kernel.gru[3]) // 3, dtype=np.float32)

    def push(self, rows: np.ndarray, final: bool = False) -> np.ndarray:
        return self.push_together([self], [rows], final)[0]

    @staticmethod
    def push_together(
        streams: Sequence[AudioCNNStream], rows: Sequence[np.ndarray], final: bool = False
    ) -> list[np.ndarray]:
        """:meth:`push` of ``rows[i]`` to ``streams[i]`` (all of one kernel), the convolutions
        and the output layer one matrix product for the new frames of all of them (the GRU, when
        there is one, stream by stream): their outputs, in order."""
        kernel = streams[0].kernel
        hs = []
        for stream, r in zip(streams, rows):
            if not len(r):
                r = np.zeros((0, stream.width), dtype=np.float32)
            elif kernel.fusion is not None:
                r = kernel.fusion.forward(r)
            hs.append(r)
        hs = ConvStackStream.push_together([stream.convs for stream in streams], hs, final)
        if kernel.gru is not None:
            hs = [stream._recur(h) for stream, h in zip(streams, hs)]
        out = kernel._output(np.concatenate(hs))
        return [out[a:b] for a, b in pairwise(np.cumsum([0, *map(len, hs)]).tolist())]

    def _recur(self, h: np.ndarray) -> np.ndarray:
        """The GRU over the next convolution outputs ``h``, from the state the last push left."""
        assert self.kernel.gru is not None and self._state is not None  # a state is kept only for a GRU
        if not len(h):
            return np.zeros((0, len(self._state)), dtype=np.float32)
        h = _gru(h, *self.kernel.gru, state=self._state)
        self._state = h[-1]
        return h


class EncoderDecoderKernel:
    """The NumPy forward pass of ``AudioEncoderDecoder``: conv encoder, bidirectional GRU
    layers (torch's gate order r, z, n), linear output and CTC head (when it has one); behind
    a :class:`LayerFusionKernel` when it reads ``fusion_layers`` encoder hidden states."""

    def __init__(
        self, weights: Mapping[str, np.ndarray], pads: Sequence[tuple[int, int]], layers: int, fusion_layers: int = 0
    ):
        self.fusion = _fusion(weights, fusion_layers)
        self.encoder = ConvStackKernel(weights, "encoder", pads)
        self.gru: list[list[GRUWeights]] = []
        for layer in range(layers):
            self.gru.append([_gru_weights(weights, f"decoder.{{}}_l{layer}{suffix}") for suffix in ("", "_reverse")])
        self.out_weight = np.asarray(weights["output.weight"], dtype=np.float32).T
        self.out_bias = np.asarray(weights["output.bias"], dtype=np.float32)
        self.phone_head = _phone_head(weights)

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        return self.forward_with_phones(inputs)[0]

    def forward_with_phones(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The outputs and the phone posteriors (``None`` without a CTC head) of ``inputs``."""
        h = self.encoder.forward(inputs if self.fusion is None else self.fusion.forward(inputs))
        for forward, backward in self.gru:
            h = np.concatenate([_gru(h, *forward), _gru(h[::-1], *backward)[::-1]], axis=1)
        return (h @ self.out_weight + self.out_bias).astype(np.float64), _posteriors(self.phone_head, h)


GRUWeights = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""One GRU direction's weights as :func:`_gru` takes them: input weights (transposed), input
bias, recurrent weights (transposed), recurrent bias."""


def _gru_weights(weights: Mapping[str, np.ndarray], pattern: str) -> GRUWeights:
    """The GRU direction whose torch weights are named ``pattern.format("weight_ih")`` and so on."""

    def array(name: str) -> np.ndarray:
        return np.asarray(weights[pattern.format(name)], dtype=np.float32)

    return array("weight_ih").T.copy(), array("bias_ih"), array("weight_hh").T.copy(), array("bias_hh")


def _gru(
    x: np.ndarray,
    w_ih: np.ndarray,
    b_ih: np.ndarray,
    w_hh: np.ndarray,
    b_hh: np.ndarray,
    state: np.ndarray | None = None,
) -> np.ndarray:
    """One GRU direction over ``x`` (frames × inputs) from ``state`` (zeros by default), as torch computes it."""
    hidden = w_hh.shape[0]
    drive = x @ w_ih + b_ih  # the input terms of every frame at once
    h = np.zeros(hidden, dtype=np.float32) if state is None else state
    out = np.empty((len(x), hidden), dtype=np.float32)
    for t in range(len(x)):
        if not t % TURN_FRAMES:
            give_turn()
        recurrent = h @ w_hh + b_hh
        rz = 1.0 / (1.0 + np.exp(-(drive[t, : 2 * hidden] + recurrent[: 2 * hidden])))
        n = np.tanh(drive[t, 2 * hidden :] + rz[:hidden] * recurrent[2 * hidden :])
        h = (1.0 - rz[hidden:]) * n + rz[hidden:] * h
        out[t] = h
    return out


class LSTMKernel:
    """The NumPy forward pass of ``DeepLSTM``: dense tanh layer, ``layers`` LSTM layers (each
    direction run over the utterance, torch's gate order i, f, g, o), linear output."""

    def __init__(self, weights: Mapping[str, np.ndarray], layers: int, bidirectional: bool):
        w = {k: np.asarray(v, dtype=np.float64) for k, v in weights.items()}
        self.dense = (w["dense.weight"].T, w["dense.bias"])
        self.output = (w["output.weight"].T, w["output.bias"])
        self.layers = []
        for k in range(layers):
            directions = []
            for suffix in ("", "_reverse") if bidirectional else ("",):
                directions.append(
                    (
                        w[f"lstm.weight_ih_l{k}{suffix}"].T,
                        w[f"lstm.weight_hh_l{k}{suffix}"].T,
                        w[f"lstm.bias_ih_l{k}{suffix}"] + w[f"lstm.bias_hh_l{k}{suffix}"],
                    )
                )
            self.layers.append(directions)

    def forward(self, inputs: np.ndarray) -> np.ndarray:
        """Outputs (frames × outputs) for one utterance's input rows."""
        h = np.tanh(np.asarray(inputs, dtype=np.float64) @ self.dense[0] + self.dense[1])
        for directions in self.layers:
            runs = [_lstm_run(h, *directions[0])]
            if len(directions) > 1:
                runs.append(_lstm_run(h[::-1], *directions[1])[::-1])
            h = np.concatenate(runs, axis=1)
        return h @ self.output[0] + self.output[1]


def _lstm_run(x: np.ndarray, w_in: np.ndarray, w_hidden: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """One LSTM direction over ``x`` (frames × inputs): the hidden state at every frame."""
    n_hidden = w_hidden.shape[0]
    drive = x @ w_in + bias
    h, c = np.zeros(n_hidden), np.zeros(n_hidden)
    out = np.empty((len(x), n_hidden))
    for t in range(len(x)):
        if not t % TURN_FRAMES:
            give_turn()
        gates = drive[t] + h @ w_hidden
        i, f = 1 / (1 + np.exp(-gates[:n_hidden])), 1 / (1 + np.exp(-gates[n_hidden : 2 * n_hidden]))
        g, o = np.tanh(gates[2 * n_hidden : 3 * n_hidden]), 1 / (1 + np.exp(-gates[3 * n_hidden :]))
        c = f * c + i * g
        h = o * np.tanh(c)
        out[t] = h
    return out
