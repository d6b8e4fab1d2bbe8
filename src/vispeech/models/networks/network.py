"""The shared base of the trainable networks: inputs, targets, fit, predict, learned state.

A phone network (:class:`PhoneNetwork`) reads per-frame input vectors
(:class:`~vispeech.models.networks.encoding.InputEncoding`) at its own frame rate (the
corpus's unless ``fps`` is set) and predicts target channels:

- ``targets="mouth"`` (default): the thesis's 18 reduced mouth channels
  (:data:`~vispeech.motion.arkit.THESIS_CHANNELS`; the Left channel of every left/right pair);
- ``"all"``: every channel of :data:`~vispeech.motion.arkit.MOUTH_CHANNELS` the corpus has;
- ``"articulatory"``: Beskow-style jaw opening, lip aperture, lip width and protrusion
  (:data:`~vispeech.motion.arkit.ARTICULATORY_CHANNELS`), which the corpus's tracks must
  carry (:func:`vispeech.corpus.articulation.with_articulatory_tracks` measures them on landmarks);
- or a list of channel names of the corpus tracks.

With ``mirror`` on, each predicted ``...Left`` channel whose ``...Right`` twin is not
predicted is copied to it on output. ARKit outputs are clipped to [0, 1].

Targets may be start/end zero-centred (the thesis: the straight line from the first to the
last frame's pose is subtracted from each utterance; at prediction the mean start/end pose of
the training data is added back) and standardised per channel (z-scores over the training
frames). Training runs on torch (the ``train`` extra); prediction runs on NumPy from the
learned ``weights_`` (:mod:`vispeech.models.networks.kernels`), so a trained network needs no
torch. Given a ``checkpoint_dir``, :meth:`~Network.fit` writes its training state there after
every epoch and, when the folder already holds one of the same network, resumes from it.
"""

from __future__ import annotations

import copy
import json
import math
from abc import abstractmethod
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Self, TypeVar

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.limits import check_fps
from vispeech.models.contract import Estimator, InputT
from vispeech.models.fitting import FitRun, show_progress, training_split
from vispeech.models.history import TrainingHistory
from vispeech.models.networks.encoding import InputEncoding
from vispeech.models.persistence import FOLDER_NAMES, write_model
from vispeech.models.streams import ModelStream, WindowStream
from vispeech.motion.arkit import ARKIT_NAMES, ARTICULATORY_CHANNELS, MOUTH_CHANNELS, THESIS_CHANNELS
from vispeech.motion.track import Track

if TYPE_CHECKING:
    import torch

    from vispeech.models.networks.audio_encoding import AudioEncoding
    from vispeech.models.networks.training import TrainingState

PHONE_INPUT_PARAMS: dict[str, Any] = {
    "inputs": "phones",
    "language": None,
    "linguistic": False,
    "position": False,
}
"""How a phone network encodes its phones (:class:`~vispeech.models.networks.encoding.InputEncoding`)."""

TRAINING_PARAMS: dict[str, Any] = {
    "targets": "mouth",
    "mirror": True,
    "fps": None,
    "zero_center": False,
    "standardize": False,
    "optimizer": "adam",
    "learning_rate": 1e-3,
    "momentum": 0.9,
    "lr_step_down": False,
    "l2": 0.0,
    "motion_weight": 0.0,
    "epochs": 100,
    "patience": 10,
    "seed": 0,
}
"""Targets, optimiser and training budget: hyper-parameters every network has."""

COMMON_PARAMS: dict[str, Any] = {**PHONE_INPUT_PARAMS, **TRAINING_PARAMS}
"""Hyper-parameters every phone network has (see the module docstring and ``docs/networks.md``)."""

TARGET_SETS = ("mouth", "all", "articulatory")
"""The named sets of channels ``targets`` may be (else a list of channel names)."""


def check_windows(input_window: object, output_window: object) -> None:
    """Refuse a sliding-window model's windows unless ``1 <= output_window <= input_window``,
    whole numbers with an even difference (the output window centred in the input one)."""
    kx, ky = input_window, output_window
    if not (isinstance(kx, int) and isinstance(ky, int) and 1 <= ky <= kx and (kx - ky) % 2 == 0):
        raise VispeechError(
            f"windows must satisfy 1 <= output_window <= input_window with an even difference, got {kx} and {ky}"
        )


def check_training_params(p: Mapping[str, Any]) -> None:
    """Raise :class:`VispeechError` on a bad value of the training parameters ``p`` has (the
    targets, the budget, the batch size, the seed, the optimiser's, the frame rate, the loss's
    motion weight, the switches), before any of them reaches a library."""
    targets = p.get("targets", "mouth")
    if not (isinstance(targets, list) and all(isinstance(t, str) for t in targets)) and targets not in TARGET_SETS:
        raise VispeechError(f"targets must be mouth, all, articulatory or a list of channels, got {targets!r}")
    for key in ("epochs", "patience", "batch_size"):
        if key in p and not (whole_number(p[key]) and p[key] >= 1) and not (key == "patience" and p[key] is None):
            stop = " (or null: no early stopping)" if key == "patience" else ""
            raise VispeechError(f"{key} must be a whole number of 1 or more{stop}, got {p[key]!r}")
    if "seed" in p and not (whole_number(p["seed"]) and 0 <= p["seed"] < 2**32):
        raise VispeechError(f"seed must be a whole number within 0..{2**32 - 1}, got {p['seed']!r}")
    if "learning_rate" in p and not (_finite(p["learning_rate"]) and p["learning_rate"] > 0):
        raise VispeechError(f"learning_rate must be a number > 0, got {p['learning_rate']!r}")
    if "momentum" in p and not (_finite(p["momentum"]) and 0 <= p["momentum"] < 1):
        raise VispeechError(f"momentum must be a number in [0, 1), got {p['momentum']!r}")
    if "l2" in p and not (_finite(p["l2"]) and p["l2"] >= 0):
        raise VispeechError(f"l2 must be a number >= 0, got {p['l2']!r}")
    if "motion_weight" in p and not (_finite(p["motion_weight"]) and p["motion_weight"] >= 0):
        raise VispeechError(f"motion_weight must be a number >= 0, got {p['motion_weight']!r}")
    if p.get("fps") is not None:
        if not _finite(p["fps"]):
            raise VispeechError(f"fps must be null (the corpus's rate) or a number, got {p['fps']!r}")
        check_fps(p["fps"], "fps")
    for key in ("mirror", "standardize", "zero_center", "lr_step_down", "linguistic", "position"):
        if key in p and not isinstance(p[key], bool):
            raise VispeechError(f"{key} must be true or false, got {p[key]!r}")


def whole_number(value: Any) -> bool:
    """Whether ``value`` is an int (a flag is not one)."""
    return isinstance(value, int) and not isinstance(value, bool)


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


_BUDGET_PARAMS = frozenset({"epochs", "patience"})
"""Hyper-parameters a resumed run may change: the training budget."""

EncodingT = TypeVar("EncodingT", bound="InputEncoding | AudioEncoding")
"""How a family encodes its inputs: :class:`~vispeech.models.networks.encoding.InputEncoding`
(phones) or :class:`~vispeech.models.networks.audio_encoding.AudioEncoding` (audio)."""


def sequence_batches(
    examples: list[tuple[np.ndarray, np.ndarray]],
    rng: np.random.Generator | None,
    size: int,
    prepare: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Utterance batches of ``size`` (shuffled with ``rng``; in order when it is ``None``): inputs
    (each through ``prepare`` first, e.g. padded for a window) and targets padded at the end to
    the batch's longest, with each utterance's frame count and the mask of its real frames."""
    order = np.arange(len(examples)) if rng is None else rng.permutation(len(examples))
    batches = []
    for start in range(0, len(order), size):
        chosen = [examples[i] for i in order[start : start + size]]
        longest = max(len(y) for _, y in chosen)
        prepared = [x if prepare is None else prepare(x) for x, _ in chosen]
        inputs = np.stack([np.pad(x, ((0, longest - len(y)), (0, 0))) for x, (_, y) in zip(prepared, chosen)])
        targets = np.stack([np.pad(y, ((0, longest - len(y)), (0, 0))) for _, y in chosen])
        lengths = np.array([len(y) for _, y in chosen])
        batches.append((inputs, targets, lengths, np.arange(longest)[None, :] < lengths[:, None]))
    return batches


class Network(Estimator[InputT], Generic[InputT, EncodingT]):
    """Base of the networks, generic in their inputs and how they encode them (phones:
    :class:`PhoneNetwork`; audio: the audio networks); families define the torch module,
    batches, loss and NumPy forward pass."""

    encoding_: EncodingT
    """The input encoding, learned at fit."""

    def _check_params(self) -> None:
        p = self._params
        self._check_inputs()
        check_training_params(p)
        if p["optimizer"] not in ("adam", "sgd"):
            raise VispeechError(f"unknown optimizer {p['optimizer']!r} (use adam or sgd)")
        self._check_architecture()
        self._kernel = None

    # -- inputs (phones: PhoneNetwork; audio: the audio networks) ---------------------------

    @abstractmethod
    def _check_inputs(self) -> None:
        """Raise :class:`VispeechError` on bad input-encoding parameters."""

    @abstractmethod
    def _make_encoding(self, train_set: list, corpus) -> EncodingT:
        """The input encoding fitted to the training data."""

    @abstractmethod
    def _encoding_from_dict(self, data: dict) -> EncodingT:
        """The input encoding that ``to_dict`` gave ``data``."""

    @abstractmethod
    def _encode_example(self, utterance, n_frames: int):
        """The inputs of one training utterance over ``n_frames`` frames at ``fps_``."""

    @abstractmethod
    def _check_warm(self, train_set: list) -> None:
        """Raise :class:`VispeechError` when the fitted encoding cannot take ``train_set`` (a warm start)."""

    # -- what families define --------------------------------------------------------------

    def _check_architecture(self) -> None:
        """Raise :class:`VispeechError` on bad architecture parameters."""

    @abstractmethod
    def _build_module(self, n_inputs: int, n_outputs: int) -> torch.nn.Module:
        """The torch module to train (weights named as in :attr:`weights_`)."""

    @abstractmethod
    def _batches(self, examples: list[tuple[np.ndarray, np.ndarray]], rng: np.random.Generator | None) -> list:
        """One epoch's batches (shuffled with ``rng``; in order when it is ``None``)."""

    @abstractmethod
    def _data_loss(self, module: torch.nn.Module, batch) -> tuple[torch.Tensor, float]:
        """Loss of one batch without weight decay, and its weight in the epoch mean."""

    @abstractmethod
    def _make_kernel(self):
        """The NumPy forward pass over :attr:`weights_` (see :mod:`vispeech.models.networks.kernels`)."""

    # -- channels --------------------------------------------------------------------------

    @property
    def outputs(self) -> tuple[str, ...]:
        """The predicted channels: learned at fit, else those the ``targets`` parameter names."""
        return getattr(self, "outputs_", None) or self._requested(None)

    @property
    def channels(self) -> tuple[str, ...]:
        """Output channels: the predicted ones, then mirrored Right twins."""
        outputs = self.outputs
        if not self._params["mirror"]:
            return outputs
        twins = tuple(
            c[: -len("Left")] + "Right"
            for c in outputs
            if c.endswith("Left") and c[: -len("Left")] + "Right" not in outputs
        )
        return outputs + twins

    def _requested(self, available: tuple[str, ...] | None) -> tuple[str, ...]:
        targets = self._params["targets"]
        if targets == "mouth":
            return THESIS_CHANNELS
        if targets == "all":
            return tuple(c for c in MOUTH_CHANNELS if available is None or c in available)
        if targets == "articulatory":
            return ARTICULATORY_CHANNELS
        return tuple(targets)

    # -- fitting ---------------------------------------------------------------------------

    def _fit(self, corpus, run: FitRun) -> Self:
        """Train on ``corpus`` (see :func:`~vispeech.models.fitting.training_split`); returns ``self``.

        Learns ``encoding_``, ``outputs_``, ``fps_``, ``stats_``, ``weights_`` and ``history_``.
        ``checkpoint_dir``: a folder that receives the model and its training state after every
        epoch (a loadable model folder, replaced as a whole). ``resume_from``: a checkpoint (or a
        saved model) of this network with the same hyper-parameters but the budget (``epochs``,
        ``patience``) to go on from; it may be ``checkpoint_dir`` itself. ``num_threads``: torch's
        threads during the fit (``None``: torch's default).
        ``warm_start`` (scikit-learn's name): a fitted network starts from its weights and
        normalisation instead of afresh, with a fresh optimiser and history (speaker adaptation).
        """
        import torch

        train_set, validation_set = training_split(corpus)
        resumed = run.resume_from
        warm = run.warm_start and self.is_fitted and resumed is None
        self._begin_fit(train_set, corpus, resumed, warm)
        examples = [self._example(u) for u in train_set]
        if resumed is None and not warm:
            self.stats_ = self._stats(examples)
        examples = [(x, self._normalise(y)) for x, y in examples]
        held_out = [(x, self._normalise(y)) for x, y in map(self._example, validation_set)]
        torch.manual_seed(self._params["seed"])
        module = self._build_module(self.encoding_.size, len(self.outputs_))
        if warm or resumed is not None:  # start from what the network knows
            module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in self.weights_.items()})
        state = self._resumed_state(resumed, module) if resumed is not None else None
        state = self._train_module(module, state, examples, held_out, run)
        self._take_weights(module.state_dict(), state.history)
        return self

    def _begin_fit(self, train_set: list, corpus, resume_from: Path | None, warm: bool) -> None:
        """Take the learned state of the run in ``resume_from``, check a warm start's data, or
        prepare afresh (:meth:`_prepare`)."""
        if resume_from is not None:
            learned = self._resumable(resume_from)._learned_state()
            assert learned is not None  # _resumable takes a fitted run only
            self._set_learned_state(*learned)
        elif warm:
            missing = [c for c in self.outputs_ if c not in train_set[0].track.channels]
            if missing:
                raise VispeechError(f"the corpus tracks lack the channels this model predicts: {', '.join(missing)}")
            self._check_warm(train_set)
        else:
            self._prepare(train_set, corpus)

    def _resumed_state(self, folder: Path, module: torch.nn.Module) -> TrainingState:
        """The training state saved in ``folder`` (its last weights loaded into ``module``); a plain
        saved model holds its best weights only, so it goes on with a fresh optimiser."""
        from vispeech.models.networks.training import TrainingState, load_state

        if (folder / "training_state.json").is_file():
            return load_state(folder, module)
        return TrainingState(
            history=self.history_,
            best_weights=copy.deepcopy(module.state_dict()),
            best_loss=_best_loss(self.history_),
        )

    def _train_module(
        self,
        module: torch.nn.Module,
        state: TrainingState | None,
        examples: list[tuple[np.ndarray, np.ndarray]],
        held_out: list[tuple[np.ndarray, np.ndarray]],
        run: FitRun,
    ) -> TrainingState:
        """Train ``module`` on the normalised ``examples`` (from ``state`` when resuming), writing
        the run's checkpoint after every epoch when it has one; returns the final training state."""
        checkpoint = run.checkpoint_dir
        import torch

        from vispeech.models.networks.training import train

        p = self._params
        optimizer: torch.optim.Optimizer
        if p["optimizer"] == "adam":
            optimizer = torch.optim.Adam(module.parameters(), lr=p["learning_rate"])
        else:
            optimizer = torch.optim.SGD(module.parameters(), lr=p["learning_rate"], momentum=p["momentum"])
        decayed = [w for w in module.parameters() if w.ndim > 1]

        def batch_loss(batch) -> tuple[torch.Tensor, float]:
            loss, weight = self._data_loss(module, batch)
            if p["l2"]:
                loss = loss + p["l2"] * sum((w**2).sum() for w in decayed)
            return loss, weight

        def validation_loss() -> float | None:
            if not held_out:
                return None
            losses = [self._data_loss(module, b) for b in self._batches(held_out, None)]
            return float(sum(loss.item() * w for loss, w in losses) / sum(w for _, w in losses))

        def on_epoch(progress_state: TrainingState) -> None:
            assert checkpoint is not None  # train is given on_epoch only with a checkpoint folder
            assert progress_state.best_weights is not None  # kept from the first epoch on
            self._take_weights(progress_state.best_weights, progress_state.history)
            self._write_checkpoint(checkpoint, module, progress_state)

        threads = torch.get_num_threads()
        if run.num_threads:
            torch.set_num_threads(int(run.num_threads))
        try:
            return train(
                module,
                optimizer,
                lambda rng: self._batches(examples, rng),
                batch_loss,
                validation_loss,
                epochs=p["epochs"],
                learning_rate=p["learning_rate"],
                patience=p["patience"],
                lr_step_down=p["lr_step_down"],
                seed=p["seed"],
                progress=show_progress(run.progress),
                state=state,
                on_epoch=on_epoch if checkpoint is not None else None,
            )
        finally:
            torch.set_num_threads(threads)

    def _take_weights(self, weights: dict, history: TrainingHistory) -> None:
        self.weights_ = {k: v.detach().numpy().copy() for k, v in weights.items()}
        self.history_ = copy.deepcopy(history)
        self._kernel = None

    def _write_checkpoint(self, folder: Path, module, state) -> None:
        """Save the model so far with the training state beside it, replacing ``folder`` as a whole."""
        from vispeech.models.networks.training import save_state

        with atomic_output_dir(folder, replaces=FOLDER_NAMES) as staging:
            write_model(self, staging, self.name)
            save_state(state, module, staging)

    def _resumable(self, folder: Path) -> Self:
        """The saved run in ``folder``, if it is one of this network with the same parameters."""
        saved = type(self).load(folder)
        if not saved.is_fitted:
            raise VispeechError(f"cannot resume from {folder}: it holds no trained {self.family} model")
        theirs, mine = _comparable(saved.get_params()), _comparable(self.get_params())
        if theirs != mine:
            changed = sorted(k for k in mine if mine[k] != theirs.get(k))
            raise VispeechError(f"cannot resume from {folder}: parameters differ ({', '.join(changed)})")
        return saved

    def _prepare(self, train_set: list, corpus) -> None:
        """Fix frame rate, output channels and input encoding from the training data
        (forgetting what an earlier fit learned)."""
        for name in ("weights_", "stats_", "history_"):
            self.__dict__.pop(name, None)
        self._kernel = None
        p = self._params
        first = train_set[0]
        self.fps_ = float(p["fps"] or first.track.fps)
        available = tuple(first.track.channels)
        self.outputs_ = self._requested(available)
        missing = [c for c in self.outputs_ if c not in available]
        if missing:
            raise VispeechError(f"the corpus tracks lack target channels {', '.join(missing)}")
        if not self.outputs_:
            raise VispeechError("the corpus tracks have none of the mouth channels")
        self.encoding_ = self._make_encoding(train_set, corpus)

    def _example(self, utterance) -> tuple[np.ndarray, np.ndarray]:
        """``(inputs, raw targets)`` of one utterance at the model's frame rate."""
        track = utterance.track
        missing = [c for c in self.outputs_ if c not in track.channels]
        if missing:
            raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} lacks channels {', '.join(missing)}")
        track = track.select(self.outputs_)
        if track.fps != self.fps_:
            track = track.resample(self.fps_)
        return self._encode_example(utterance, track.n_frames), track.values

    def _stats(self, examples: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
        n = len(self.outputs_)
        neutral = np.zeros(n)
        if self._params["zero_center"]:
            neutral = np.mean([(y[0] + y[-1]) / 2 for _, y in examples], axis=0)
            centred = np.concatenate([y - _ramp(y) for _, y in examples])
        else:
            centred = np.concatenate([y for _, y in examples])
        mean, scale = np.zeros(n), np.ones(n)
        if self._params["standardize"]:
            mean, scale = centred.mean(axis=0), np.maximum(centred.std(axis=0), 1e-3)
        return {"mean": mean, "scale": scale, "neutral": neutral}

    def _normalise(self, y: np.ndarray) -> np.ndarray:
        if self._params["zero_center"]:
            y = y - _ramp(y)
        return ((y - self.stats_["mean"]) / self.stats_["scale"]).astype(np.float32)

    def _denormalise(self, y: np.ndarray) -> np.ndarray:
        """Model outputs to output-channel values (mirrored, ARKit ones clipped to [0, 1])."""
        values = y * self.stats_["scale"] + self.stats_["mean"] + self.stats_["neutral"]
        twins, arkit = self._output_columns()
        values = np.concatenate([values, values[..., twins]], axis=-1)
        values[..., arkit] = np.clip(values[..., arkit], 0.0, 1.0)
        return values

    def _output_columns(self) -> tuple[list[int], np.ndarray]:
        """The predicted column each mirrored twin copies, and which output channels are ARKit's."""
        key = (self.outputs_, self.channels)
        if getattr(self, "_columns_for", None) != key:
            twins = [self.outputs_.index(c[: -len("Right")] + "Left") for c in self.channels[len(self.outputs_) :]]
            self._columns = (twins, np.array([c in ARKIT_NAMES for c in self.channels]))
            self._columns_for = key
        return self._columns

    # -- prediction ------------------------------------------------------------------------

    def _has_learned(self) -> bool:
        return hasattr(self, "weights_")

    @property
    def frame_rate(self) -> float | None:
        """``fps_`` once fitted: the network predicts at its training frame rate, then resamples."""
        return getattr(self, "fps_", None)

    @property
    def kernel(self):
        """The NumPy forward pass (built once from :attr:`weights_`)."""
        self.check_fitted()
        if self._kernel is None:
            self._kernel = self._make_kernel()
        return self._kernel

    # -- learned state ---------------------------------------------------------------------

    def _learned_state(self) -> tuple[dict, dict[str, np.ndarray]] | None:
        if not hasattr(self, "weights_"):
            return None
        state = {
            "encoding": self.encoding_.to_dict(),
            "outputs": list(self.outputs_),
            "fps": self.fps_,
            "history": self.history_.to_dict(),
        }
        arrays = {f"module.{k}": v for k, v in self.weights_.items()}
        arrays |= {f"stats.{k}": v for k, v in self.stats_.items()}
        return state, arrays

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        self.encoding_ = self._encoding_from_dict(state["encoding"])
        self.outputs_ = tuple(state["outputs"])
        self.fps_ = float(state["fps"])
        self.history_ = TrainingHistory.from_dict(state["history"])
        self.stats_ = {k[6:]: v.astype(np.float64) for k, v in arrays.items() if k.startswith("stats.")}
        self.weights_ = {k[7:]: v for k, v in arrays.items() if k.startswith("module.")}
        self._kernel = None
        try:
            self._make_kernel()
        except (KeyError, ValueError) as exc:
            raise ValueError(f"weights do not fit the config: {exc}") from None


class PhoneNetwork(Network[PhoneSequence, InputEncoding]):
    """Base of the networks that animate phones (:data:`PHONE_INPUT_PARAMS` encode them)."""

    def _check_inputs(self) -> None:
        p = self._params
        InputEncoding(p["inputs"], p["language"] or "en", p["linguistic"], p["position"])

    def _make_encoding(self, train_set: list, corpus) -> InputEncoding:
        p = self._params
        language = p["language"] or getattr(corpus, "language", None) or train_set[0].phones.language
        return InputEncoding(p["inputs"], language, p["linguistic"], p["position"])

    def _encoding_from_dict(self, data: dict) -> InputEncoding:
        return InputEncoding.from_dict(data)

    def _encode_example(self, utterance, n_frames: int) -> np.ndarray:
        return self.encoding_.encode(utterance.phones, self.fps_, n_frames=n_frames)

    def _check_warm(self, train_set: list) -> None:
        self.encoding_.check(train_set[0].phones)

    def stream(self, language: str, fps: float) -> ModelStream:
        """A re-predicted recent window (:class:`~vispeech.models.streams.WindowStream`), after
        checking that the network takes ``language``'s phones."""
        self.check_fitted()
        self.encoding_.check(PhoneSequence([], language))
        return WindowStream(self, language, fps)

    def predict(self, inputs: PhoneSequence, fps: float) -> Track:
        """Tracks of ``inputs.n_frames(fps)`` frames for phones: predicted at the model's rate,
        resampled to ``fps``."""
        return self.predict_many([inputs], fps)[0]

    def predict_many(self, inputs: Sequence[PhoneSequence], fps: float) -> list[Track]:
        """:meth:`predict` of each phone sequence, the kernel run on all of them together
        (:meth:`_forward_many`)."""
        self.check_fitted()
        encoded = []
        for phones in inputs:
            self.check_inputs(phones, fps)
            self.encoding_.check(phones)
            encoded.append(self.encoding_.encode(phones, self.fps_))
        tracks = []
        for phones, outputs in zip(inputs, self._forward_many(encoded)):
            track = Track(self._denormalise(outputs), self.channels, self.fps_)
            n = phones.n_frames(fps)
            tracks.append(track if fps == self.fps_ and track.n_frames == n else track.resample(fps, n_frames=n))
        return tracks

    def _forward_many(self, inputs: list[np.ndarray]) -> list[np.ndarray]:
        """The kernel's outputs for each utterance's input rows; a family whose kernel runs
        utterances together overrides it."""
        return [self.kernel.forward(x) for x in inputs]


def _comparable(params: dict) -> dict:
    """``params`` without those a resumed run may change, as JSON would give them back."""
    return json.loads(json.dumps({k: v for k, v in params.items() if k not in _BUDGET_PARAMS}))


def _ramp(y: np.ndarray) -> np.ndarray:
    """The straight line from the first to the last frame of ``y`` (frames x channels)."""
    f = np.linspace(0.0, 1.0, len(y))[:, None] if len(y) > 1 else np.zeros((1, 1))
    return (1 - f) * y[0] + f * y[-1]


def _best_loss(history: TrainingHistory) -> float:
    if not history.best_epoch:
        return float("inf")
    i = history.best_epoch - 1
    value = history.validation_loss[i]
    return history.train_loss[i] if value is None else value
