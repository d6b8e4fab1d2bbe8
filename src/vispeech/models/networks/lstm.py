"""The LSTM baseline of Taylor et al. (2017): Fan et al.'s (2015) deep (bidirectional) LSTM.

A dense tanh layer on each frame's phone inputs, two bidirectional LSTM layers of 500 units and
a linear output per frame, dropout 0.5, mini-batches of 10 utterances (Taylor et al.: "one fully
connected layer and two LSTM layers", 500 units best of 100–3000). Trained like the other
networks (Adam, early stopping on the validation split); predicted with NumPy
(:class:`~vispeech.models.networks.kernels.LSTMKernel`). Bidirectional, it needs the whole
utterance: its stream re-predicts a recent window (:class:`~vispeech.models.streams.WindowStream`).
Taylor et al. found it "significantly worse" than the sliding window.
"""

from __future__ import annotations

from vispeech.errors import VispeechError
from vispeech.models.networks.kernels import LSTMKernel
from vispeech.models.networks.network import COMMON_PARAMS, PhoneNetwork, sequence_batches

FAN: dict = {
    **COMMON_PARAMS,
    "linguistic": True,
    "standardize": True,
    "dense": 500,
    "hidden": 500,
    "layers": 2,
    "bidirectional": True,
    "dropout": 0.5,
    "batch_size": 10,
}
"""Hyper-parameters of Taylor et al.'s LSTM baseline (``lstm-taylor``)."""


class LSTMNetwork(PhoneNetwork):
    """Taylor et al.'s LSTM baseline. Architecture hyper-parameters: ``dense`` (units of the
    dense layer), ``hidden`` (LSTM units per direction), ``layers``, ``bidirectional``,
    ``dropout``, ``batch_size`` (utterances per update); the others are the common ones."""

    family = "lstm-taylor"
    defaults = FAN

    def _check_architecture(self) -> None:
        p = self._params
        for key in ("dense", "hidden", "layers"):
            if not (isinstance(p[key], int) and p[key] >= 1):
                raise VispeechError(f"{key} must be a whole number of 1 or more, got {p[key]!r}")
        if not 0 <= p["dropout"] < 1:
            raise VispeechError(f"dropout must be in [0, 1), got {p['dropout']!r}")
        if not isinstance(p["bidirectional"], bool):
            raise VispeechError(f"bidirectional must be true or false, got {p['bidirectional']!r}")

    @property
    def lookahead(self) -> int:
        """Frames a stream waits for: a second (the network reads the whole utterance both ways)."""
        return round(getattr(self, "fps_", None) or 25)

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import DeepLSTM

        p = self._params
        return DeepLSTM(n_inputs, n_outputs, p["dense"], p["hidden"], p["layers"], p["bidirectional"], p["dropout"])

    def _make_kernel(self) -> LSTMKernel:
        return LSTMKernel(self.weights_, self._params["layers"], self._params["bidirectional"])

    def _batches(self, examples, rng):
        import torch

        return [
            tuple(map(torch.from_numpy, batch)) for batch in sequence_batches(examples, rng, self._params["batch_size"])
        ]

    def _data_loss(self, module, batch):
        from vispeech.models.networks.training import sequence_loss

        inputs, targets, lengths, mask = batch
        loss = sequence_loss(module(inputs, lengths), targets, self._params["motion_weight"], mask)
        return loss, float(mask.sum())
