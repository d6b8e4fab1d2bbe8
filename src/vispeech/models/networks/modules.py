"""The torch modules the networks train (prediction runs on :mod:`vispeech.models.networks.kernels`).

Only training imports this module, and with it torch (the ``train`` extra).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class WindowMLP(nn.Module):
    """``(batch, Kx, inputs)`` windows to ``(batch, Ky, outputs)``: an MLP on the flat window.

    ``init="he"`` draws hidden weights from N(0, 2 / fan-in) and output weights from
    N(0, 0.05²), biases 0 (the thesis); ``"default"`` keeps torch's initialisation.
    """

    def __init__(self, n_inputs: int, n_outputs: int, input_window: int, output_window: int,
                 hidden: list[int], activation: str, dropout: list[float], init: str):
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
    total = sum(nn.functional.pad(out[:, k], (0, 0, k, ky - 1 - k)) for k in range(ky))
    return total[ky - 1: ky - 1 + n_frames] / ky


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

    def __init__(self, nets: list[RecurrentTimeDelayNet], columns: list[list[int]]):
        super().__init__()
        self.nets = nn.ModuleList(nets)
        order = [c for group in columns for c in group]
        self.register_buffer("order", torch.tensor(np.argsort(order)), persistent=False)

    def forward(self, padded: torch.Tensor) -> torch.Tensor:
        return torch.cat([net(padded) for net in self.nets], dim=-1)[..., self.order]
