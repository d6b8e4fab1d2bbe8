"""Beskow's (2004) recurrent time-delay networks, offline (ANN 1) and low-latency (ANN 2).

Each network has three layers. At frame t (of the model's frame rate, 60 fps in the
presets as in the paper):

- the input window is the input vectors of frames ``t - look_back .. t + look_ahead``
  (the sequence padded with copies of its first and last frame), fully connected to the
  hidden layer: a 1-D convolution over time with kernel ``look_back + look_ahead + 1``;
- the hidden layer is ``h_t = tanh(conv_t + Σ_{d=1..delays} R_d h_{t-d})``, fed back to
  itself with time delays 1 to ``delays`` (5; ``h`` before the first frame is 0);
- the output is linear: ``y_t = V h_t + c``.

So a network has ``H·F·K + H + delays·H² + H·O + O`` weights for ``F`` inputs per frame,
window ``K``, ``H`` hidden units and ``O`` outputs (Beskow counts ``H·18·31 + 5H² + HO + H + O``:
his 17 features plus, it seems, a bias unit per frame). ``groups`` splits the outputs over
several such networks (Beskow: occlusion, rounding, protrusion, jaw), each with its own
hidden size (``hidden`` an int or one int per group). Training is back-propagation through
time over whole utterances, ``batch_size`` utterances per update, Adam.

Presets: ``beskow`` (ANN 1): look-back 15, look-ahead 15 frames; ``beskow-lowlatency``
(ANN 2): look-back 28, look-ahead 2 (33 ms at 60 fps). Both read articulatory feature
vectors (``inputs="features"``) and standardise the targets.

:meth:`TimeDelayNetwork.predict_stream` runs the same network on phones as they arrive and
yields frame t as soon as the inputs up to ``t + look_ahead`` are known.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.contract import register_model
from vispeech.models.networks.network import COMMON_PARAMS, NeuralControlModel

_BESKOW = {
    **COMMON_PARAMS,
    "inputs": "features",
    "standardize": True,
    "fps": 60.0,
    "epochs": 200,
    "look_back": 15,
    "look_ahead": 15,
    "hidden": 50,
    "delays": 5,
    "groups": None,
    "batch_size": 8,
}

PRESETS: dict[str, dict] = {
    "beskow": _BESKOW,
    "beskow-lowlatency": {**_BESKOW, "look_back": 28, "look_ahead": 2},
}
"""Parameters of ANN 1 (``beskow``) and ANN 2 (``beskow-lowlatency``)."""


@register_model
class TimeDelayNetwork(NeuralControlModel):
    """Beskow's recurrent time-delay network; ``preset`` is ``"beskow"`` or ``"beskow-lowlatency"``.

    Architecture parameters: ``look_back``, ``look_ahead`` (frames), ``hidden`` (units, or
    one count per group), ``delays`` (hidden feedback delays 1..delays), ``groups`` (``None``:
    one network for all outputs; else a list of channel-name lists covering the outputs),
    ``batch_size`` (utterances per update). The others are the common network parameters.
    """

    name = "tdnn-beskow"
    presets = PRESETS
    default_preset = "beskow"
    preset_names = {"beskow": "tdnn-beskow", "beskow-lowlatency": "tdnn-lowlatency"}

    def _check_params(self) -> None:
        p = self._params
        for key in ("look_back", "look_ahead"):
            if not (isinstance(p[key], int) and p[key] >= 0):
                raise VispeechError(f"{key} must be a whole number of frames >= 0, got {p[key]!r}")
        if not (isinstance(p["delays"], int) and p["delays"] >= 1):
            raise VispeechError(f"delays must be >= 1, got {p['delays']!r}")

    @property
    def window(self) -> int:
        return self._params["look_back"] + self._params["look_ahead"] + 1

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import GroupedNetworks, RecurrentTimeDelayNet

        p = self._params
        groups = p["groups"] or [list(self.outputs)]
        columns = []
        for group in groups:
            unknown = [c for c in group if c not in self.outputs]
            if unknown:
                raise VispeechError(f"groups name channels the model does not predict: {', '.join(unknown)}")
            columns.append([self.outputs.index(c) for c in group])
        if sorted(c for group in columns for c in group) != list(range(n_outputs)):
            raise VispeechError(f"groups must cover each output channel once: {', '.join(self.outputs)}")
        hidden = list(p["hidden"]) if isinstance(p["hidden"], list | tuple) else [p["hidden"]] * len(groups)
        if len(hidden) != len(groups):
            raise VispeechError(f"hidden needs one size per group ({len(groups)}), got {hidden}")
        nets = [RecurrentTimeDelayNet(n_inputs, len(c), self.window, h, p["delays"]) for c, h in zip(columns, hidden)]
        return GroupedNetworks(nets, columns)

    def _pad(self, inputs: np.ndarray) -> np.ndarray:
        return np.pad(inputs, ((self._params["look_back"], self._params["look_ahead"]), (0, 0)), mode="edge")

    def _batches(self, examples, rng):
        import torch

        order = np.arange(len(examples)) if rng is None else rng.permutation(len(examples))
        size = self._params["batch_size"]
        batches = []
        for start in range(0, len(order), size):
            chosen = [examples[i] for i in order[start:start + size]]
            longest = max(len(y) for _, y in chosen)
            inputs = np.stack([np.pad(self._pad(x), ((0, longest - len(x)), (0, 0))) for x, _ in chosen])
            targets = np.stack([np.pad(y, ((0, longest - len(y)), (0, 0))) for _, y in chosen])
            mask = np.arange(longest)[None, :] < np.array([len(y) for _, y in chosen])[:, None]
            batches.append((torch.from_numpy(inputs), torch.from_numpy(targets), torch.from_numpy(mask)))
        return batches

    def _data_loss(self, module, batch):
        from vispeech.models.networks.training import sequence_loss

        inputs, targets, mask = batch
        loss = sequence_loss(module(inputs), targets, self._params["motion_weight"], mask)
        return loss, float(mask.sum())

    def _infer(self, module, inputs: np.ndarray) -> np.ndarray:
        import torch

        return module(torch.from_numpy(self._pad(inputs)).double()[None])[0].numpy()

    def predict_stream(self, phone_events: Iterable[Phone], language: str = "en") -> Iterator[tuple[int, np.ndarray]]:
        """Predict while phones arrive: yield ``(frame index, values)`` at the model's fps.

        ``phone_events`` gives the phones of ``language`` in time order (each with its start
        and end in seconds). Frame t (at ``t / fps`` s) comes out as soon as the inputs of
        frames up to ``t + look_ahead`` are known, i.e. once a phone ending after
        ``(t + look_ahead) / fps`` has arrived; the last frames come when the stream ends.
        ``values`` follow :attr:`channels`. The frames equal those of :meth:`predict` at
        ``self.fps`` on the whole sequence.
        """
        import torch

        module = self._inference_module()
        self.encoding.check(PhoneSequence([], language))
        back, ahead = self._params["look_back"], self._params["look_ahead"]
        rows: list[np.ndarray] = []  # encoded input frames so far
        recent: list[Phone] = []  # the phones still needed to encode the next frames
        past = module.initial_state(torch.float64)
        emitted = 0

        def ready(final: bool) -> Iterator[tuple[int, np.ndarray]]:
            nonlocal emitted, past
            n = len(rows)
            while emitted < n and (final or emitted + ahead < n):
                index = np.clip(np.arange(emitted - back, emitted + ahead + 1), 0, n - 1)
                window = torch.from_numpy(np.stack([rows[i] for i in index])).double()[None]
                with torch.no_grad():
                    out, past = module.step(window, past)
                yield emitted, self._denormalise(out[0].numpy())
                emitted += 1

        for phone in phone_events:
            if not phone.end > phone.start or (recent and phone.start < recent[-1].end - 1e-6):
                raise VispeechError(f"phone {phone.symbol} at {phone.start:.3f} s is empty or starts "
                                    "before the previous one ends")
            recent.append(phone)
            sequence = PhoneSequence(recent, language)
            known = sequence.n_frames(self.fps)
            if known > len(rows):
                rows.extend(self.encoding.encode(sequence, self.fps, n_frames=known, start_frame=len(rows)))
                # Keep the phone before the first one covering the frame before the next to
                # encode, so a silence gap after it starts where it ends (as offline).
                keep = np.searchsorted(sequence.ends, (len(rows) - 1) / self.fps, side="right")
                recent = recent[max(keep - 1, 0):]
            yield from ready(final=False)
        yield from ready(final=True)


@register_model
class LowLatencyNetwork(TimeDelayNetwork):
    """:class:`TimeDelayNetwork` with the ``beskow-lowlatency`` preset (ANN 2) by default."""

    name = "tdnn-lowlatency"
    default_preset = "beskow-lowlatency"

