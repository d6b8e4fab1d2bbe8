"""The torch modules the networks train (prediction runs on :mod:`vispeech.models.networks.kernels`).

Only training imports this module, and with it torch (the ``train`` extra).
"""

from __future__ import annotations

from typing import cast

import numpy as np
import torch
from torch import nn


class WindowMLP(nn.Module):
    """``(batch, Kx, inputs)`` windows to ``(batch, Ky, outputs)``: an MLP on the flat window.

    ``init="he"`` draws hidden weights from N(0, 2 / fan-in) and output weights from
    N(0, 0.05²), biases 0 (the thesis); ``"default"`` keeps torch's initialisation.
    """

    def __init__(
        self,
        n_inputs: int,
        n_outputs: int,
        input_window: int,
        output_window: int,
        hidden: list[int],
        activation: str,
        dropout: list[float],
        init: str,
    ):
        super().__init__()
        self.output_window, self.n_outputs = output_window, n_outputs
        layers: list[nn.Module] = []
        width = input_window * n_inputs
        for size, rate in zip(hidden, dropout, strict=True):
            linear = nn.Linear(width, size)
            if init == "he":
                nn.init.normal_(linear.weight, 0.0, float(np.sqrt(2.0 / width)))
                nn.init.zeros_(linear.bias)
            layers += [linear, nn.Tanh() if activation == "tanh" else nn.LeakyReLU(0.1)]
            if rate:
                layers.append(nn.Dropout(rate))
            width = size
        out = nn.Linear(width, output_window * n_outputs)
        if init == "he":
            nn.init.normal_(out.weight, 0.0, 0.05)
            nn.init.zeros_(out.bias)
        layers.append(out)
        self.layers = nn.Sequential(*layers)

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        out = self.layers(windows.flatten(1))
        return out.view(-1, self.output_window, self.n_outputs)


def edge_pad(values: np.ndarray, before: int, after: int | None = None) -> torch.Tensor:
    """``values`` (frames x columns) with copies of its first and last rows added."""
    after = before if after is None else after
    return torch.from_numpy(np.pad(values, ((before, after), (0, 0)), mode="edge"))


def windows(padded: torch.Tensor, size: int) -> torch.Tensor:
    """Every window of ``size`` consecutive rows: ``(windows, size, columns)``."""
    return padded.unfold(0, size, 1).transpose(1, 2)


def overlap_average(out: torch.Tensor, n_frames: int) -> torch.Tensor:
    """Frame-wise mean of overlapping output windows ``(n_frames + Ky - 1, Ky, channels)``.

    Window w predicts frames ``w - Ky + 1 .. w``; every frame gets exactly Ky predictions.
    """
    ky = out.shape[1]
    # sum's start, 0, is never the result: there is at least one window (ky >= 1)
    total = cast(torch.Tensor, sum(nn.functional.pad(out[:, k], (0, 0, k, ky - 1 - k)) for k in range(ky)))
    return total[ky - 1 : ky - 1 + n_frames] / ky


class RecurrentTimeDelayNet(nn.Module):
    """One network: input window convolution, hidden layer fed back at delays 1..``delays``."""

    def __init__(self, n_inputs: int, n_outputs: int, window: int, hidden: int, delays: int):
        super().__init__()
        self.window, self.delays, self.hidden = window, delays, hidden
        self.input = nn.Conv1d(n_inputs, hidden, window)
        self.recurrent = nn.Linear(delays * hidden, hidden, bias=False)
        self.output = nn.Linear(hidden, n_outputs)

    def initial_state(self, batch: int, dtype: torch.dtype) -> list[torch.Tensor]:
        """Hidden states of the ``delays`` frames before the first: zeros, newest first."""
        return [torch.zeros(batch, self.hidden, dtype=dtype) for _ in range(self.delays)]

    def forward(self, padded: torch.Tensor) -> torch.Tensor:
        """``(batch, frames + window - 1, inputs)`` padded inputs to ``(batch, frames, outputs)``."""
        drive = self.input(padded.transpose(1, 2)).transpose(1, 2)
        past = self.initial_state(len(padded), padded.dtype)
        states = []
        for t in range(drive.shape[1]):
            h = torch.tanh(drive[:, t] + self.recurrent(torch.cat(past, dim=1)))
            past = [h, *past[:-1]]
            states.append(h)
        return self.output(torch.stack(states, dim=1))


class GroupedNetworks(nn.Module):
    """Several networks, each predicting some outputs; outputs come back in the model's order."""

    order: torch.Tensor
    """The permutation putting the networks' outputs in the model's order (a buffer)."""

    def __init__(self, nets: list[RecurrentTimeDelayNet], columns: list[list[int]]):
        super().__init__()
        self.nets = nn.ModuleList(nets)
        order = [c for group in columns for c in group]
        self.register_buffer("order", torch.tensor(np.argsort(order)), persistent=False)

    def forward(self, padded: torch.Tensor) -> torch.Tensor:
        return torch.cat([net(padded) for net in self.nets], dim=-1)[..., self.order]


class FrameNorm(nn.Module):
    """Layer normalisation over the channels of each frame of ``(batch, channels, frames)``:
    a frame never depends on its neighbours' statistics, so streaming equals offline."""

    def __init__(self, channels: int):
        super().__init__()
        self.norm = nn.LayerNorm(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.norm(x.transpose(1, 2)).transpose(1, 2)


class ConvStack(nn.Module):
    """1-D convolutions over time, each followed by ReLU and :class:`FrameNorm`; layer i sees
    ``right[i]`` frames ahead and ``kernels[i] - 1 - right[i]`` behind (zero padding)."""

    def __init__(self, n_inputs: int, channels: list[int], kernels: list[int], right: list[int], dropout: float):
        super().__init__()
        self.pads = [(k - 1 - r, r) for k, r in zip(kernels, right)]
        sizes = [n_inputs, *channels]
        self.convs = nn.ModuleList(nn.Conv1d(a, b, k) for a, b, k in zip(sizes, sizes[1:], kernels))
        self.norms = nn.ModuleList(FrameNorm(c) for c in channels)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(batch, frames, inputs)`` to ``(batch, frames, channels[-1])``."""
        h = x.transpose(1, 2)
        for conv, norm, pad in zip(self.convs, self.norms, self.pads):
            h = self.dropout(norm(torch.relu(conv(nn.functional.pad(h, pad)))))
        return h.transpose(1, 2)


class LayerFusion(nn.Module):
    """PhISANet's All-Enc fusion: ``(batch, frames, layers · width)`` hidden states of a speech
    encoder (layer-major) to ``(batch, frames, width)``, their sum weighted by the softmax of
    ``layers`` learned logits (zeros at first: the plain mean)."""

    def __init__(self, layers: int, width: int):
        super().__init__()
        self.layers, self.width = layers, width
        self.logits = nn.Parameter(torch.zeros(layers))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weights = torch.softmax(self.logits, dim=0)
        return torch.einsum("btlw,l->btw", x.unflatten(-1, (self.layers, self.width)), weights)


def _fused(n_inputs: int, fusion_layers: int) -> tuple[LayerFusion | None, int]:
    """The fusion in front of a network reading ``fusion_layers`` hidden states (none when 0), and its output width."""
    if not fusion_layers:
        return None, n_inputs
    return LayerFusion(fusion_layers, n_inputs // fusion_layers), n_inputs // fusion_layers


class AudioCNN(nn.Module):
    """PhISANet's streaming decoder: a :class:`ConvStack`, a forward-only GRU of ``recurrent``
    units when that is not 0 (it carries context from the past only, so streaming stays exact),
    a linear output and an optional CTC head, behind a :class:`LayerFusion` when it reads
    ``fusion_layers`` encoder hidden states."""

    def __init__(
        self,
        n_inputs: int,
        n_outputs: int,
        channels: list[int],
        kernels: list[int],
        right: list[int],
        dropout: float,
        n_phones: int,
        fusion_layers: int = 0,
        recurrent: int = 0,
    ):
        super().__init__()
        self.fusion, width = _fused(n_inputs, fusion_layers)
        self.encoder = ConvStack(width, channels, kernels, right, dropout)
        self.gru = nn.GRU(channels[-1], recurrent, batch_first=True) if recurrent else None
        top = recurrent or channels[-1]
        self.output = nn.Linear(top, n_outputs)
        self.ctc = nn.Linear(top, n_phones + 1) if n_phones else None

    def forward(self, x: torch.Tensor, lengths: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Outputs ``(batch, frames, outputs)`` and CTC logits ``(batch, frames, phones + 1)`` or ``None``."""
        h = self.encoder(x if self.fusion is None else self.fusion(x))
        if self.gru is not None:  # padding trails each utterance, so it never reaches a frame's output
            h, _ = self.gru(h)
        return self.output(h), None if self.ctc is None else self.ctc(h)


class AudioEncoderDecoder(nn.Module):
    """An offline encoder-decoder: a centred :class:`ConvStack` encoder, a bidirectional GRU
    decoder over whole utterances, a linear output and an optional CTC head on the decoder,
    behind a :class:`LayerFusion` when it reads ``fusion_layers`` encoder hidden states."""

    def __init__(
        self,
        n_inputs: int,
        n_outputs: int,
        channels: list[int],
        kernels: list[int],
        hidden: int,
        layers: int,
        dropout: float,
        n_phones: int,
        fusion_layers: int = 0,
    ):
        super().__init__()
        self.fusion, width = _fused(n_inputs, fusion_layers)
        self.encoder = ConvStack(width, channels, kernels, [(k - 1) // 2 for k in kernels], dropout)
        self.decoder = nn.GRU(
            channels[-1],
            hidden,
            num_layers=layers,
            batch_first=True,
            bidirectional=True,
            dropout=dropout if layers > 1 else 0.0,
        )
        self.output = nn.Linear(2 * hidden, n_outputs)
        self.ctc = nn.Linear(2 * hidden, n_phones + 1) if n_phones else None

    def forward(self, x: torch.Tensor, lengths: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        h = self.encoder(x if self.fusion is None else self.fusion(x))
        packed = nn.utils.rnn.pack_padded_sequence(h, lengths.cpu(), batch_first=True, enforce_sorted=False)
        q, _ = self.decoder(packed)
        q, _ = nn.utils.rnn.pad_packed_sequence(q, batch_first=True, total_length=x.shape[1])
        return self.output(q), None if self.ctc is None else self.ctc(q)


class DeepLSTM(nn.Module):
    """``(batch, frames, inputs)`` to ``(batch, frames, outputs)``: a dense tanh layer, ``layers``
    (bidirectional) LSTM layers of ``hidden`` units, a linear output (Fan et al. 2015 as Taylor
    et al. 2017 ran it). ``lengths`` (batch) marks each sequence's real frames."""

    def __init__(
        self, n_inputs: int, n_outputs: int, dense: int, hidden: int, layers: int, bidirectional: bool, dropout: float
    ) -> None:
        super().__init__()
        self.dense = nn.Linear(n_inputs, dense)
        self.dropout = nn.Dropout(dropout)
        self.lstm = nn.LSTM(
            dense,
            hidden,
            num_layers=layers,
            batch_first=True,
            bidirectional=bidirectional,
            dropout=dropout if layers > 1 else 0.0,
        )
        self.output = nn.Linear(hidden * (2 if bidirectional else 1), n_outputs)

    def forward(self, x: torch.Tensor, lengths: torch.Tensor | None = None) -> torch.Tensor:
        h = self.dropout(torch.tanh(self.dense(x)))
        if lengths is not None:
            packed = nn.utils.rnn.pack_padded_sequence(h, lengths.cpu(), batch_first=True, enforce_sorted=False)
            h, _ = self.lstm(packed)
            h, _ = nn.utils.rnn.pad_packed_sequence(h, batch_first=True, total_length=x.shape[1])
        else:
            h, _ = self.lstm(h)
        return self.output(self.dropout(h))
