"""Beskow's (2004) recurrent time-delay networks, offline (ANN 1) and low-latency (ANN 2).

Each network has three layers. At frame t (of the model's frame rate, 60 fps in the
hyper-parameters as in the paper):

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

Families: ``tdnn-beskow`` (ANN 1): look-back 15, look-ahead 15 frames; ``tdnn-lowlatency``
(ANN 2): look-back 28, look-ahead 2 (33 ms at 60 fps). Both read articulatory feature
vectors (``inputs="features"``) and standardise the targets.

:meth:`TimeDelayNetwork.stream` runs the same network on phones as they arrive and gives
frame t as soon as the inputs up to ``t + look_ahead`` are known (:class:`RecurrentStream`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence, n_frames_for
from vispeech.errors import VispeechError
from vispeech.models.networks.kernels import RecurrentKernel
from vispeech.models.networks.network import COMMON_PARAMS, PhoneNetwork, sequence_batches, whole_number
from vispeech.models.streams import ModelStream, ResampledFrames, pushed_phones, rate_ratio

BESKOW: dict = {
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
"""Hyper-parameters of ANN 1 (``tdnn-beskow``); ANN 2 (``tdnn-lowlatency``) looks 28 back and 2 ahead."""


def _channel_names(group: object) -> bool:
    return isinstance(group, list) and bool(group) and all(isinstance(name, str) for name in group)


class TimeDelayNetwork(PhoneNetwork):
    """Beskow's recurrent time-delay network, ANN 1 (look-back and look-ahead 15 frames).

    Architecture hyper-parameters: ``look_back``, ``look_ahead`` (frames), ``hidden`` (units,
    or one count per group), ``delays`` (hidden feedback delays 1..delays), ``groups``
    (``None``: one network for all outputs; else a list of channel-name lists covering the
    outputs), ``batch_size`` (utterances per update). The others are the common network ones.
    """

    family = "tdnn-beskow"
    defaults = BESKOW

    def _check_architecture(self) -> None:
        p = self._params
        for key in ("look_back", "look_ahead"):
            if not (isinstance(p[key], int) and p[key] >= 0):
                raise VispeechError(f"{key} must be a whole number of frames >= 0, got {p[key]!r}")
        if not (isinstance(p["delays"], int) and p["delays"] >= 1):
            raise VispeechError(f"delays must be >= 1, got {p['delays']!r}")
        groups, hidden = p["groups"], p["hidden"]
        if not (groups is None or (isinstance(groups, list) and groups and all(map(_channel_names, groups)))):
            raise VispeechError(f"groups must be a list of lists of channel names, got {groups!r}")
        counts = hidden if isinstance(hidden, list) else [hidden]
        if not (counts and all(whole_number(h) and h >= 1 for h in counts)):
            raise VispeechError(f"hidden must be a whole number of units, 1 or more (or one per group), got {hidden!r}")

    @property
    def window(self) -> int:
        return self._params["look_back"] + self._params["look_ahead"] + 1

    @property
    def lookahead(self) -> int:
        """Frames of input after frame t (at the model's own frame rate) that frame t needs."""
        return self._params["look_ahead"]

    def _group_columns(self) -> list[list[int]]:
        """The output columns of each group's network."""
        groups = self._params["groups"] or [list(self.outputs)]
        columns = []
        for group in groups:
            unknown = [c for c in group if c not in self.outputs]
            if unknown:
                raise VispeechError(f"groups name channels the model does not predict: {', '.join(unknown)}")
            columns.append([self.outputs.index(c) for c in group])
        if sorted(c for group in columns for c in group) != list(range(len(self.outputs))):
            raise VispeechError(f"groups must cover each output channel once: {', '.join(self.outputs)}")
        return columns

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import GroupedNetworks, RecurrentTimeDelayNet

        p = self._params
        columns = self._group_columns()
        hidden = list(p["hidden"]) if isinstance(p["hidden"], list | tuple) else [p["hidden"]] * len(columns)
        if len(hidden) != len(columns):
            raise VispeechError(f"hidden needs one size per group ({len(columns)}), got {hidden}")
        nets = [RecurrentTimeDelayNet(n_inputs, len(c), self.window, h, p["delays"]) for c, h in zip(columns, hidden)]
        return GroupedNetworks(nets, columns)

    def _make_kernel(self) -> RecurrentKernel:
        events = [i for i, name in enumerate(self.encoding_.names) if ">" in name]  # phone-onset transitions
        return RecurrentKernel(
            self.weights_, self._group_columns(), self._params["look_back"], self._params["look_ahead"], events
        )

    def _forward_many(self, inputs: list[np.ndarray]) -> list[np.ndarray]:
        """The kernel over all the utterances at once (:meth:`RecurrentKernel.forward_many`)."""
        return self.kernel.forward_many(inputs)

    def _pad(self, inputs: np.ndarray) -> np.ndarray:
        return np.pad(inputs, ((self._params["look_back"], self._params["look_ahead"]), (0, 0)), mode="edge")

    def _batches(self, examples, rng):
        import torch

        return [
            (torch.from_numpy(x), torch.from_numpy(y), torch.from_numpy(mask))
            for x, y, _, mask in sequence_batches(examples, rng, self._params["batch_size"], self._pad)
        ]

    def _data_loss(self, module, batch):
        from vispeech.models.networks.training import sequence_loss

        inputs, targets, mask = batch
        loss = sequence_loss(module(inputs), targets, self._params["motion_weight"], mask)
        return loss, float(mask.sum())

    def stream(self, language: str, fps: float) -> ModelStream:
        """The exact recurrence run frame by frame as phones arrive (:class:`RecurrentStream`)."""
        self.check_fitted()
        self.encoding_.check(PhoneSequence([], language))
        return RecurrentStream(self, language, fps)


class LowLatencyNetwork(TimeDelayNetwork):
    """Beskow's ANN 2: :class:`TimeDelayNetwork` looking 28 frames back and 2 ahead (33 ms at 60 fps)."""

    family = "tdnn-lowlatency"
    defaults = {**BESKOW, "look_back": 28, "look_ahead": 2}


class RecurrentStream(ModelStream[Iterable[Phone]]):
    """A time-delay network driven phone by phone.

    Model frame t (at the model's ``fps_``) is computed once the phones cover frame
    ``t + look_ahead``; stream frame k (at the stream's ``fps``) is interpolated from the model
    frames around ``k / fps`` as :meth:`TimeDelayNetwork.predict` resamples, so the stream's
    frames equal :meth:`~TimeDelayNetwork.predict`'s on the whole sequence.
    """

    model: TimeDelayNetwork

    def __init__(self, model: TimeDelayNetwork, language: str, fps: float) -> None:
        super().__init__(model, language, fps)
        self.lookahead = stream_lookahead(model.lookahead, model.fps_, self.fps)
        self._kernel = model.kernel
        self._back, self._ahead = model.get_params()["look_back"], model.lookahead  # the input window
        self._state = self._kernel.initial_state()
        self._due = 0  # model frames the phones so far make computable
        self._rows: list[np.ndarray] = []  # encoded input frames so far
        self._recent: list[Phone] = []  # the phones still needed to encode the next frames
        self._frames = ResampledFrames(model.fps_, self.fps)  # model outputs, denormalised

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        self.feed(phones)
        return self.collect()

    def feed(self, phones: Iterable[Phone]) -> None:
        """Encode the phones' input frames; the model frames they make computable are left to
        :meth:`advance_together` (or :meth:`collect`)."""
        if self.closed:
            raise VispeechError("this phone stream has ended")
        model = self.model
        new = pushed_phones(phones, self.language, self._recent[-1].end if self._recent else None)
        if new:
            self._recent += new
            self.end = new[-1].end
        sequence = PhoneSequence(self._recent, self.language)
        known = sequence.n_frames(model.fps_) if self._recent else 0
        if known > len(self._rows):  # a frame's inputs depend on the phones up to it only: encoded once a push
            self._rows.extend(model.encoding_.encode(sequence, model.fps_, n_frames=known, start_frame=len(self._rows)))
            # Keep the phone before the first one covering the frame before the next to
            # encode, so a silence gap after it starts where it ends (as offline).
            keep = int(np.searchsorted(sequence.ends, (len(self._rows) - 1) / model.fps_, side="right"))
            self._recent = self._recent[max(keep - 1, 0) :]
        self._due = len(self._rows) - model.lookahead

    def collect(self) -> tuple[int, np.ndarray]:
        self.advance_together([self])
        return self._give(min(self._frames.ready(), n_frames_for(self.end, self.fps)))

    def finish(self) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this phone stream has ended")
        self._due = len(self._rows)
        self.advance_together([self])
        out = self._give(n_frames_for(self.end, self.fps)) if self._rows else self._empty()
        self.close()
        return out

    @classmethod
    def advance_together(cls, streams: Sequence[RecurrentStream]) -> None:
        """Compute the model frames due in ``streams``: each stream's drives from its input rows'
        cached window terms, then one recurrence step (:meth:`RecurrentKernel.advance`) per frame
        for all the streams sharing a network."""
        groups: dict[int, list[RecurrentStream]] = {}
        for stream in streams:
            if stream._frames.computed < stream._due:
                groups.setdefault(id(stream._kernel), []).append(stream)
        for group in groups.values():
            group.sort(key=lambda s: s._due - s._frames.computed, reverse=True)
            kernel, model = group[0]._kernel, group[0].model
            states = [np.stack(parts) for parts in zip(*(s._state for s in group))]
            steps = [s._due - s._frames.computed for s in group]  # frames each stream computes
            drives = [s._drives(n) for s, n in zip(group, steps)]
            outputs = []
            for k in range(steps[0]):
                active = sum(1 for n in steps if n > k)
                out, stepped = kernel.advance(np.stack([d[k] for d in drives[:active]]), [s[:active] for s in states])
                for state, new in zip(states, stepped):
                    state[:active] = new
                outputs.append(out)
            rows = iter(model._denormalise(np.concatenate(outputs)))  # frame by frame, streams in order
            for k in range(steps[0]):
                for stream in group[: len(outputs[k])]:
                    stream._frames.add(next(rows))
            for b, stream in enumerate(group):
                stream._state = [state[b] for state in states]

    def _drives(self, steps: int) -> np.ndarray:
        """The drives (steps × hidden units, :meth:`RecurrentKernel.window_terms`) of the next
        ``steps`` model frames, the first and last input rows repeated beyond the ends as offline."""
        t = self._frames.computed
        rows = np.clip(np.arange(t - self._back, t + steps + self._ahead), 0, len(self._rows) - 1)
        return self._kernel.window_terms(np.stack([self._rows[i] for i in rows]))[self._back : self._back + steps]

    def _give(self, upto: int) -> tuple[int, np.ndarray]:
        """Stream frames ``emitted .. upto - 1`` (:class:`~vispeech.models.streams.ResampledFrames`)."""
        if upto <= self.emitted or not self._frames.computed:
            return self._empty()
        start, self.emitted = self.emitted, upto
        return start, self._frames.give(start, upto)


def stream_lookahead(ahead: int, model_fps: float, fps: float) -> int:
    """Stream frames after frame k that the phones must cover before :class:`RecurrentStream` gives k.

    Stream frame k interpolates model frames up to ``m = ceil(k · model_fps / fps)``, which needs
    the inputs up to model frame ``m + ahead``. ``m`` lies at most ``1 - 1/q`` model frames after
    ``k``'s time, where ``q`` is the denominator of ``model_fps / fps`` (0 at the model's own rate or
    a whole multiple of it; nearly 1 for a ratio that is no simple fraction).
    """
    simple = rate_ratio(model_fps, fps)
    slack = 1.0 - 1.0 / simple.denominator if simple is not None else 1.0
    return max(0, math.ceil((ahead + slack) * fps / model_fps - 1e-9))
