"""The shared base of the trainable torch networks: inputs, targets, fit, predict, save, load.

A network reads per-frame input vectors (:class:`~vispeech.models.networks.encoding.InputEncoding`)
at its own frame rate (the corpus's unless ``fps`` is set) and predicts target channels:

- ``targets="mouth"`` (default): the thesis's 18 reduced mouth channels
  (:data:`THESIS_CHANNELS`; the Left channel of every left/right pair);
- ``"all"``: every channel of :data:`~vispeech.motion.arkit.MOUTH_CHANNELS` the corpus has;
- ``"articulatory"``: Beskow-style jaw opening, lip aperture, lip width and protrusion
  measured on the corpus's landmarks (:func:`vispeech.corpus.articulation.articulatory_parameters`);
- or a list of channel names of the corpus tracks.

With ``mirror`` on, each predicted ``...Left`` channel whose ``...Right`` twin is not
predicted is copied to it on output. ARKit outputs are clipped to [0, 1].

Targets may be start/end zero-centred (the thesis: the straight line from the first to the
last frame's pose is subtracted from each utterance; at prediction the mean start/end pose of
the training data is added back) and standardised per channel (z-scores over the training
frames). ``fit`` trains on ``corpus.split("train")`` and validates on
``corpus.split("validation")`` when the corpus has splits; otherwise on all of it, with an
optional ``validation`` set. A saved model folder holds ``config.json`` (the common model
format plus a ``state`` entry with what fitting learned), ``weights.safetensors``,
``loss_curve.png`` and, for a checkpoint written during fitting, ``training_state.json`` and
``training_state.safetensors`` (see :mod:`vispeech.models.networks.training`).
"""

from __future__ import annotations

import copy
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.models.contract import ControlModel
from vispeech.models.networks.encoding import InputEncoding
from vispeech.models.networks.training import STATE_JSON, TrainingHistory
from vispeech.motion.arkit import ARKIT_NAMES, MOUTH_CHANNELS
from vispeech.motion.track import Track
from vispeech.postprocess import LEARNED_JAW

if TYPE_CHECKING:
    import torch

    from vispeech.models.networks.training import TrainingState

THESIS_CHANNELS: tuple[str, ...] = (
    "jawForward", "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker",
    "mouthSmileLeft", "mouthDimpleLeft", "mouthStretchLeft",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthLowerDownLeft", "mouthUpperUpLeft",
    "cheekPuff", "cheekSquintLeft", "noseSneerLeft",
)
"""The thesis's 18 output channels, in its order (Left kept of each pair)."""

WEIGHTS = "weights.safetensors"
LOSS_CURVE = "loss_curve.png"

COMMON_PARAMS: dict = {
    "inputs": "phones",
    "language": None,
    "linguistic": False,
    "position": False,
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
    "progress": True,
    "num_threads": None,
}
"""Parameters every network has (see the module docstring and ``docs/networks.md``)."""


class NeuralControlModel(ControlModel):
    """Base of the torch networks; subclasses define the module, batches and loss."""

    presets: dict[str, dict] = {}
    default_preset: str = ""
    preset_names: dict[str, str] = {}
    """Registered model name of each preset: a network saves under its preset's name."""

    def __init__(self, params: Mapping | None = None, **options):
        chosen = {**(params or {}), **options}.get("preset", self.default_preset)
        if chosen not in self.presets:
            raise VispeechError(f"unknown preset {chosen!r} (use {', '.join(self.presets)})")
        super().__init__({**self.presets[chosen], **(params or {})}, **options)
        self.name = self.preset_names[chosen]
        p = self._params
        InputEncoding(p["inputs"], p["language"] or "en", p["linguistic"], p["position"])
        if p["optimizer"] not in ("adam", "sgd"):
            raise VispeechError(f"unknown optimizer {p['optimizer']!r} (use adam or sgd)")
        if not (isinstance(p["targets"], list | tuple) or p["targets"] in ("mouth", "all", "articulatory")):
            raise VispeechError(f"targets must be mouth, all, articulatory or a list of channels, got {p['targets']!r}")
        self._check_params()
        self._module: torch.nn.Module | None = None
        self._inference: torch.nn.Module | None = None
        self.encoding: InputEncoding | None = None
        self.outputs: tuple[str, ...] = ()
        self.fps: float | None = None
        self.history = TrainingHistory()
        self._stats: dict[str, np.ndarray] = {}

    @classmethod
    def default_params(cls) -> dict:
        return {"preset": cls.default_preset, **copy.deepcopy(cls.presets[cls.default_preset])}

    # -- what subclasses define ------------------------------------------------------------

    def _check_params(self) -> None:
        """Raise :class:`VispeechError` on bad architecture parameters."""

    def _build_module(self, n_inputs: int, n_outputs: int) -> torch.nn.Module:
        raise NotImplementedError

    def _batches(self, examples: list[tuple[np.ndarray, np.ndarray]], rng: np.random.Generator | None) -> list:
        """One epoch's batches (shuffled with ``rng``; in order when it is ``None``)."""
        raise NotImplementedError

    def _data_loss(self, module: torch.nn.Module, batch) -> tuple[torch.Tensor, float]:
        """Loss of one batch without weight decay, and its weight in the epoch mean."""
        raise NotImplementedError

    def _infer(self, module: torch.nn.Module, inputs: np.ndarray) -> np.ndarray:
        """Normalised outputs (frames x outputs) for one utterance's inputs, in float64."""
        raise NotImplementedError

    # -- channels --------------------------------------------------------------------------

    @property
    def channels(self) -> tuple[str, ...]:
        """Output channels: the predicted ones, then mirrored Right twins."""
        outputs = self.outputs or self._requested(None)
        if not self._params["mirror"]:
            return outputs
        twins = tuple(
            c[: -len("Left")] + "Right" for c in outputs
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
            from vispeech.corpus.articulation import ARTICULATORY_CHANNELS

            return ARTICULATORY_CHANNELS
        return tuple(targets)

    @property
    def is_trained(self) -> bool:
        return self._module is not None and self.history.best_epoch > 0

    # -- fitting ---------------------------------------------------------------------------

    def fit(
        self,
        corpus,
        *,
        validation: Iterable | None = None,
        resume_from: str | os.PathLike | None = None,
        checkpoint_dir: str | os.PathLike | None = None,
    ) -> NeuralControlModel:
        """Train on ``corpus`` (any iterable of objects with ``.phones`` and ``.track``).

        A corpus with splits (:class:`vispeech.corpus.Corpus`) trains on its ``train`` split
        and validates on its ``validation`` split unless ``validation`` is given; anything
        else trains on all of it. ``resume_from`` continues a run from a checkpoint folder (or a saved model: then the
        optimizer starts afresh) up to ``epochs`` epochs in all; ``checkpoint_dir`` receives a
        checkpoint after every epoch. Returns ``self``.
        """
        import torch

        from vispeech.models.networks.training import train

        train_set, validation_set = _split(corpus, validation)
        if not train_set:
            raise VispeechError("cannot fit on an empty corpus")
        p = self._params
        state = None
        if resume_from is not None:
            state = self._resume(Path(resume_from))
        else:
            self._prepare(train_set, corpus)
        examples = [self._example(u) for u in train_set]
        if resume_from is None:
            self._set_stats(examples)
            torch.manual_seed(p["seed"])
            self._module = self._build_module(self.encoding.size, len(self.outputs))
        examples = [(x, self._normalise(y)) for x, y in examples]
        held_out = [(x, self._normalise(y)) for x, y in map(self._example, validation_set)]
        module = self._module
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

        def checkpoint(progress: TrainingState) -> None:
            self._write(Path(checkpoint_dir), progress.best_weights, progress.history, progress)

        threads = torch.get_num_threads()
        if p["num_threads"]:
            torch.set_num_threads(int(p["num_threads"]))
        try:
            state = train(
                module, optimizer, lambda rng: self._batches(examples, rng), batch_loss, validation_loss,
                epochs=p["epochs"], learning_rate=p["learning_rate"], patience=p["patience"],
                lr_step_down=p["lr_step_down"], seed=p["seed"], progress=p["progress"], state=state,
                on_epoch=checkpoint if checkpoint_dir is not None else None,
            )
        finally:
            torch.set_num_threads(threads)
        self.history = state.history
        self._inference = None
        self.postprocessing = dict(LEARNED_JAW)
        return self

    def _prepare(self, train_set: list, corpus) -> None:
        """Fix language, encoding, frame rate and output channels from the training data."""
        p = self._params
        first = train_set[0]
        _phones_of(first)
        language = p["language"] or getattr(corpus, "language", None) or first.phones.language
        self.encoding = InputEncoding(p["inputs"], language, p["linguistic"], p["position"])
        self.fps = float(p["fps"] or first.track.fps)
        if p["targets"] == "articulatory":
            self.outputs = self._requested(None)
        else:
            available = tuple(first.track.channels)
            self.outputs = self._requested(available)
            missing = [c for c in self.outputs if c not in available]
            if missing:
                raise VispeechError(f"the corpus tracks lack target channels {', '.join(missing)}")
            if not self.outputs:
                raise VispeechError("the corpus tracks have none of the mouth channels")
        self.history = TrainingHistory()

    def _example(self, utterance) -> tuple[np.ndarray, np.ndarray]:
        """``(inputs, raw targets)`` of one utterance at the model's frame rate."""
        phones = _phones_of(utterance)
        if self._params["targets"] == "articulatory":
            from vispeech.corpus.articulation import articulatory_parameters

            track = articulatory_parameters(utterance)
        else:
            track = utterance.track
            missing = [c for c in self.outputs if c not in track.channels]
            if missing:
                raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} lacks channels {', '.join(missing)}")
            track = track.select(self.outputs)
        if track.fps != self.fps:
            track = track.resample(self.fps)
        inputs = self.encoding.encode(phones, self.fps, n_frames=track.n_frames)
        return inputs, track.values

    def _set_stats(self, examples: list[tuple[np.ndarray, np.ndarray]]) -> None:
        n = len(self.outputs)
        neutral = np.zeros(n)
        if self._params["zero_center"]:
            neutral = np.mean([(y[0] + y[-1]) / 2 for _, y in examples], axis=0)
            centred = np.concatenate([y - _ramp(y) for _, y in examples])
        else:
            centred = np.concatenate([y for _, y in examples])
        mean, scale = np.zeros(n), np.ones(n)
        if self._params["standardize"]:
            mean, scale = centred.mean(axis=0), np.maximum(centred.std(axis=0), 1e-3)
        self._stats = {"mean": mean, "scale": scale, "neutral": neutral}

    def _normalise(self, y: np.ndarray) -> np.ndarray:
        if self._params["zero_center"]:
            y = y - _ramp(y)
        return ((y - self._stats["mean"]) / self._stats["scale"]).astype(np.float32)

    def _denormalise(self, y: np.ndarray) -> np.ndarray:
        """Model outputs to output-channel values (mirrored, ARKit ones clipped to [0, 1])."""
        values = y * self._stats["scale"] + self._stats["mean"] + self._stats["neutral"]
        extra = [self.outputs.index(c[: -len("Right")] + "Left") for c in self.channels[len(self.outputs):]]
        values = np.concatenate([values, values[..., extra]], axis=-1)
        arkit = np.array([c in ARKIT_NAMES for c in self.channels])
        values[..., arkit] = np.clip(values[..., arkit], 0.0, 1.0)
        return values

    # -- prediction ------------------------------------------------------------------------

    def _inference_module(self) -> torch.nn.Module:
        """A float64 copy of the trained module in eval mode (cached)."""
        if not self.is_trained:
            raise VispeechError(f"model is not trained: fit {self.name} on a corpus or load a trained one")
        if self._inference is None:
            self._inference = copy.deepcopy(self._module).double().eval()
        return self._inference

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        """Tracks of ``phones.n_frames(fps)`` frames: predicted at the model's rate, resampled to ``fps``."""
        import torch

        module = self._inference_module()
        phones.validate()
        self.encoding.check(phones)
        inputs = self.encoding.encode(phones, self.fps)
        with torch.no_grad():
            values = self._denormalise(self._infer(module, inputs))
        track = Track(values, self.channels, self.fps)
        n = phones.n_frames(fps)
        if fps != self.fps or track.n_frames != n:
            track = track.resample(fps, n_frames=n)
        return track

    # -- saving ----------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write config, weights and the loss curve into folder ``path`` atomically."""
        weights = None if self._module is None else self._module.state_dict()
        self._write(Path(path), weights, self.history, None)
        return Path(path)

    def _write(self, folder: Path, weights: dict | None, history: TrainingHistory, state: TrainingState | None) -> None:
        import torch
        from safetensors.torch import save as to_safetensors

        from vispeech.models.networks.training import save_state

        config = self._config([])
        config["state"] = None if self.encoding is None else {
            "encoding": self.encoding.to_dict(),
            "outputs": list(self.outputs),
            "fps": self.fps,
            "history": history.to_dict(),
        }
        with atomic_output_dir(folder) as staging:
            (staging / "config.json").write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
            if weights is not None:
                tensors = {f"module.{k}": v for k, v in weights.items()}
                tensors |= {f"stats.{k}": torch.from_numpy(v) for k, v in self._stats.items()}
                tensors = {k: v.detach().contiguous().clone() for k, v in tensors.items()}
                (staging / WEIGHTS).write_bytes(to_safetensors(tensors))
            if history.epochs:
                history.plot(staging / LOSS_CURVE)
            if state is not None:
                save_state(state, self._module, staging)

    @classmethod
    def _from_folder(cls, folder: Path, config: dict) -> NeuralControlModel:
        """Rebuild a saved network: config, then ``weights.safetensors`` if the folder has one."""
        from safetensors.torch import load_file

        model = cls(config["params"])
        saved = config.get("state")
        if saved is not None:
            try:
                model.encoding = InputEncoding.from_dict(saved["encoding"])
                model.outputs = tuple(saved["outputs"])
                model.fps = float(saved["fps"])
                model.history = TrainingHistory.from_dict(saved["history"])
            except (KeyError, TypeError, ValueError) as exc:
                raise VispeechError(f"corrupt model config in {folder}: {exc}") from None
            if (folder / WEIGHTS).is_file():
                try:
                    tensors = load_file(folder / WEIGHTS)
                except (OSError, ValueError) as exc:
                    raise VispeechError(f"cannot read model weights {folder / WEIGHTS}: {exc}") from None
                model._stats = {
                    k[6:]: v.numpy().astype(np.float64) for k, v in tensors.items() if k.startswith("stats.")
                }
                module = model._build_module(model.encoding.size, len(model.outputs))
                try:
                    module.load_state_dict({k[7:]: v for k, v in tensors.items() if k.startswith("module.")})
                except RuntimeError as exc:
                    raise VispeechError(f"model weights in {folder} do not fit its config: {exc}") from None
                model._module = module
        return model

    def _resume(self, folder: Path) -> TrainingState:
        """Take over a saved run: its learned set-up, weights and (if any) training state."""
        from vispeech.models.networks.training import TrainingState, load_state

        saved = ControlModel.load(folder)
        if saved.name != self.name or not isinstance(saved, NeuralControlModel) or saved._module is None:
            raise VispeechError(f"cannot resume from {folder}: it holds no trained {self.name} model")
        architecture = _comparable(saved.get_params())
        mine = _comparable(self.get_params())
        if architecture != mine:
            changed = sorted(k for k in mine if mine[k] != architecture.get(k))
            raise VispeechError(f"cannot resume from {folder}: parameters differ ({', '.join(changed)})")
        self.encoding, self.outputs, self.fps = saved.encoding, saved.outputs, saved.fps
        self._stats, self._module = saved._stats, saved._module
        if (folder / STATE_JSON).is_file():
            return load_state(folder, self._module)
        best = {k: v.clone() for k, v in self._module.state_dict().items()}
        # A plain saved model holds its best weights only: go on from them with a fresh optimizer.
        return TrainingState(history=saved.history, best_weights=best, best_loss=_best_loss(saved.history))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(preset={self._params['preset']!r})"


_RUN_PARAMS = frozenset({"epochs", "patience", "progress", "num_threads"})
"""Parameters that may change between a run and its resumption."""


def _comparable(params: dict) -> dict:
    """``params`` without those a resumed run may change, as JSON would give them back."""
    return json.loads(json.dumps({k: v for k, v in params.items() if k not in _RUN_PARAMS}))


def _split(corpus, validation: Iterable | None) -> tuple[list, list]:
    if hasattr(corpus, "split"):
        train_set = list(corpus.split("train"))
        held_out = list(corpus.split("validation")) if validation is None else list(validation)
        return train_set, held_out
    return list(corpus), list(validation or [])


def _phones_of(utterance) -> PhoneSequence:
    if getattr(utterance, "phones", None) is None:
        raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} has no phones: align the corpus first")
    return utterance.phones


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
