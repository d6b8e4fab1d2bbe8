"""Sliding-window networks (Taylor et al. 2017; the thesis's Swedish network).

A fully connected network reads a window of ``input_window`` (Kx) frames of input vectors
and predicts ``output_window`` (Ky) frames of every target channel, centred in the input
window. Windows slide one frame at a time; the input is padded at both ends by
``(Kx + Ky) / 2 - 1`` copies of its first and last frame, so every frame lies in exactly Ky
output windows, whose predictions are averaged.

Families:

- ``sliding-window-taylor``: Kx = 11, Ky = 5, three hidden layers of 3000 tanh units with dropout 0.5, a
  linear output, squared loss on each output window, mini-batch SGD (100 windows, momentum
  0.9), phone one-hot plus linguistic indicator inputs, standardised targets.
- ``sliding-window-thesis``: Kx = Ky = 15, hidden layers of 0.5·Kx·nf and Kx·nb units (675 -> 338 -> 270 ->
  270 for nf = 45 inputs and nb = 18 outputs) with LeakyReLU (0.1) and dropout 0.6 / 0.1,
  He initialisation (output layer N(0, 0.05²)), one utterance per update with the loss
  (MSE + 1.8e-8·Σ‖W‖² + 1e-4·motion term) on the overlap-averaged sequence, Adam (1e-3)
  stepped down whenever the epoch training loss rises, start/end zero-centred targets,
  early stopping after 10 epochs without a better validation loss.
"""

from __future__ import annotations

import numpy as np

from vispeech.errors import VispeechError
from vispeech.models.networks.kernels import WindowKernel
from vispeech.models.networks.network import COMMON_PARAMS, PhoneNetwork, check_windows

TAYLOR: dict = {
    **COMMON_PARAMS,
    "linguistic": True,
    "standardize": True,
    "optimizer": "sgd",
    "learning_rate": 0.01,
    "momentum": 0.9,
    "input_window": 11,
    "output_window": 5,
    "hidden": [3000, 3000, 3000],
    "activation": "tanh",
    "dropout": [0.5, 0.5, 0.5],
    "init": "default",
    "update": "windows",
    "batch_size": 100,
}
"""Hyper-parameters of Taylor et al. (2017): ``sliding-window-taylor``."""

THESIS: dict = {
    **COMMON_PARAMS,
    "zero_center": True,
    "lr_step_down": True,
    "l2": 1.8e-8,
    "motion_weight": 1e-4,
    "input_window": 15,
    "output_window": 15,
    "hidden": None,
    "activation": "leaky_relu",
    "dropout": [0.6, 0.1],
    "init": "he",
    "update": "utterance",
    "batch_size": 1,
}
"""Hyper-parameters of the thesis's network (``sliding-window-thesis``); ``hidden=None`` is its sizing rule."""

_ACTIVATIONS = ("tanh", "leaky_relu")
_INITS = ("default", "he")
"""Weight initialisations: torch's default, or He's (Kaiming normal, for the leaky ReLUs)."""


class SlidingWindowNetwork(PhoneNetwork):
    """The thesis's sliding-window network.

    Window parameters: ``input_window``, ``output_window`` (Kx - Ky even), ``hidden`` (layer
    sizes, or ``None`` for the thesis rule 0.5·Kx·inputs, Kx·outputs), ``activation``
    (``tanh`` or ``leaky_relu``), ``dropout`` (one rate per hidden layer), ``init``
    (``default`` or ``he``), ``update`` (``"windows"``: mini-batches of ``batch_size``
    windows, loss per window; ``"utterance"``: one utterance per update, loss on the
    averaged sequence). The others are the common network parameters (``docs/networks.md``).
    """

    family = "sliding-window-thesis"
    defaults = THESIS

    def _check_architecture(self) -> None:
        p = self._params
        check_windows(p["input_window"], p["output_window"])
        if p["activation"] not in _ACTIVATIONS:
            raise VispeechError(f"unknown activation {p['activation']!r} (use {' or '.join(_ACTIVATIONS)})")
        layers = 2 if p["hidden"] is None else len(p["hidden"])
        if len(p["dropout"]) != layers:
            raise VispeechError(f"dropout needs one rate per hidden layer ({layers}), got {p['dropout']}")
        rates = p["dropout"]
        if not all(isinstance(rate, int | float) and not isinstance(rate, bool) and 0 <= rate < 1 for rate in rates):
            raise VispeechError(f"dropout rates must be at least 0 and below 1, got {p['dropout']}")
        if p["init"] not in _INITS:
            raise VispeechError(f"unknown init {p['init']!r} (use {' or '.join(_INITS)})")
        if p["update"] not in ("windows", "utterance"):
            raise VispeechError(f"update must be windows or utterance, got {p['update']!r}")

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import WindowMLP

        p = self._params
        kx = p["input_window"]
        hidden = p["hidden"] or [max(1, round(0.5 * kx * n_inputs)), kx * n_outputs]
        return WindowMLP(
            n_inputs, n_outputs, kx, p["output_window"], list(hidden), p["activation"], list(p["dropout"]), p["init"]
        )

    @property
    def _pad(self) -> int:
        return (self._params["input_window"] + self._params["output_window"]) // 2 - 1

    def _batches(self, examples, rng):
        import torch

        from vispeech.models.networks.modules import edge_pad

        kx, ky = self._params["input_window"], self._params["output_window"]
        if self._params["update"] == "utterance":
            order = range(len(examples)) if rng is None else rng.permutation(len(examples))
            return [(edge_pad(examples[i][0], self._pad), torch.from_numpy(examples[i][1])) for i in order]
        inputs = [edge_pad(x, self._pad) for x, _ in examples]
        targets = [edge_pad(y, ky - 1) for _, y in examples]
        x_all, y_all = torch.cat(inputs), torch.cat(targets)
        counts = [len(y) + ky - 1 for _, y in examples]  # windows per utterance
        x_starts = np.concatenate([o + np.arange(c) for o, c in zip(_offsets(inputs), counts)])
        y_starts = np.concatenate([o + np.arange(c) for o, c in zip(_offsets(targets), counts)])
        order = np.arange(len(x_starts)) if rng is None else rng.permutation(len(x_starts))
        size = self._params["batch_size"]
        # Windows are gathered batch by batch (in _data_loss), never all at once.
        return [
            (
                x_all,
                torch.from_numpy(x_starts[chunk][:, None] + np.arange(kx)),
                y_all,
                torch.from_numpy(y_starts[chunk][:, None] + np.arange(ky)),
            )
            for chunk in (order[i : i + size] for i in range(0, len(order), size))
        ]

    def _data_loss(self, module, batch):
        from vispeech.models.networks.modules import overlap_average, windows
        from vispeech.models.networks.training import sequence_loss

        weight = self._params["motion_weight"]
        if self._params["update"] == "utterance":
            padded, target = batch
            pred = overlap_average(module(windows(padded, self._params["input_window"])), len(target))
            return sequence_loss(pred[None], target[None], weight), float(len(target))
        x_all, x_index, y_all, y_index = batch
        return sequence_loss(module(x_all[x_index]), y_all[y_index], weight), float(len(x_index))

    @property
    def lookahead(self) -> int:
        """Frames after frame t (at the model's own rate) whose inputs frame t's output windows read."""
        return self._pad

    def _make_kernel(self) -> WindowKernel:
        p = self._params
        return WindowKernel(self.weights_, p["input_window"], p["output_window"], p["activation"])


class TaylorNetwork(SlidingWindowNetwork):
    """Taylor et al.'s (2017) sliding-window network: :class:`SlidingWindowNetwork` with their hyper-parameters."""

    family = "sliding-window-taylor"
    defaults = TAYLOR


def _offsets(blocks: list) -> np.ndarray:
    """Where each block starts in their concatenation."""
    return np.cumsum([0] + [len(b) for b in blocks[:-1]])
