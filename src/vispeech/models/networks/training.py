"""The torch training loop shared by the trainable networks.

One epoch runs every batch the model hands out (shuffled by a seeded numpy generator),
then measures the validation loss. The loop keeps the weights of the best epoch (lowest
validation loss, or training loss without a validation set), stops early after
``patience`` epochs without improvement, optionally steps the learning rate down whenever
the epoch's training loss rises (the thesis schedule: halve, then fifth, in turn:
1e-3, 5e-4, 1e-4, 5e-5, ...), and can hand a :class:`TrainingState` to a callback after
each epoch so a caller may checkpoint it. A state saved with :func:`save_state` and read
with :func:`load_state` resumes exactly where it stopped: weights, optimizer moments,
random generators, epoch count and early-stopping counters.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vispeech.errors import VispeechError
from vispeech.models.history import TrainingHistory

if TYPE_CHECKING:
    import torch

STATE_JSON = "training_state.json"
STATE_TENSORS = "training_state.safetensors"


@dataclass
class TrainingState:
    """Everything needed to go on training after an epoch."""

    history: TrainingHistory = field(default_factory=TrainingHistory)
    best_loss: float = math.inf
    stale_epochs: int = 0
    lr_steps: int = 0
    best_weights: dict[str, torch.Tensor] | None = None
    optimizer: dict | None = None
    torch_rng: torch.Tensor | None = None
    numpy_rng: Mapping[str, Any] | None = None

    @property
    def epoch(self) -> int:
        """Epochs completed."""
        return self.history.epochs


def seed_everything(seed: int) -> np.random.Generator:
    """Seed torch's global generator and return a numpy generator seeded alike."""
    import torch

    torch.manual_seed(seed)
    return np.random.default_rng(seed)


def step_down_factor(steps: int) -> float:
    """Learning-rate factor after ``steps`` step-downs: 1, 0.5, 0.1, 0.05, 0.01, ..."""
    return 0.1 ** (steps // 2) * (0.5 if steps % 2 else 1.0)


def train(
    module: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    batches: Callable[[np.random.Generator], Iterable],
    batch_loss: Callable[[object], tuple[torch.Tensor, float]],
    validation_loss: Callable[[], float | None],
    *,
    epochs: int,
    learning_rate: float,
    patience: int | None = 10,
    lr_step_down: bool = False,
    seed: int = 0,
    progress: bool = True,
    state: TrainingState | None = None,
    on_epoch: Callable[[TrainingState], None] | None = None,
) -> TrainingState:
    """Train ``module`` for up to ``epochs`` epochs in all, then load its best weights.

    ``batches(rng)`` lists one epoch's batches; ``batch_loss(batch)`` returns the loss to
    minimise and the batch's weight in the epoch mean (e.g. its frame count);
    ``validation_loss()`` is called in eval mode without gradients (``None``: no validation
    set, the training loss decides). ``state`` resumes a run with its random generators (or,
    if it has none, generators seeded with ``seed`` + epochs done);
    ``on_epoch(state)`` is called after every epoch, e.g. to checkpoint. Returns the final state.
    """
    import torch
    from tqdm import tqdm

    state, rng = _resumed(state, seed, optimizer)
    while state.epoch < epochs and (patience is None or state.stale_epochs < patience):
        started = time.perf_counter()
        lr = learning_rate * step_down_factor(state.lr_steps)
        for group in optimizer.param_groups:
            group["lr"] = lr
        module.train()
        train_loss = _epoch_loss(
            optimizer, batches(rng), batch_loss, f"epoch {state.epoch + 1}/{epochs}", state.epoch + 1, progress
        )
        module.eval()
        with torch.no_grad():
            validation = validation_loss()
        _record(state, module, train_loss, validation, lr, time.perf_counter() - started, lr_step_down)
        state.optimizer = optimizer.state_dict()
        state.torch_rng = torch.get_rng_state()
        state.numpy_rng = rng.bit_generator.state
        if progress:
            shown = "" if validation is None else f", validation {validation:.4g}"
            tqdm.write(f"epoch {state.epoch}/{epochs}: training {train_loss:.4g}{shown}")
        if on_epoch is not None:
            on_epoch(state)
    if state.best_weights is not None:
        module.load_state_dict(state.best_weights)
    return state


def _resumed(
    state: TrainingState | None, seed: int, optimizer: torch.optim.Optimizer
) -> tuple[TrainingState, np.random.Generator]:
    """The state to train on (a new one for ``None``) and the NumPy generator, with the random
    generators and the optimizer restored from ``state`` where it has them."""
    import torch

    if state is None:
        return TrainingState(), seed_everything(seed)
    rng = seed_everything(seed + state.epoch)  # replaced below when the state has generators
    if state.numpy_rng is not None:
        rng.bit_generator.state = state.numpy_rng
    if state.torch_rng is not None:
        torch.set_rng_state(state.torch_rng)
    if state.optimizer is not None:
        optimizer.load_state_dict(state.optimizer)
    return state, rng


def _epoch_loss(
    optimizer: torch.optim.Optimizer,
    batches: Iterable,
    batch_loss: Callable[[object], tuple[torch.Tensor, float]],
    desc: str,
    epoch: int,
    progress: bool,
) -> float:
    """One optimiser step per batch; the epoch's training loss (the batches' weighted mean)."""
    import torch
    from tqdm import tqdm

    total, weight = 0.0, 0.0
    bar = tqdm(batches, desc=desc, unit="batch", disable=not progress, leave=False)
    for batch in bar:
        optimizer.zero_grad()
        loss, w = batch_loss(batch)
        if not torch.isfinite(loss):
            raise VispeechError(f"training diverged in epoch {epoch} (loss {loss.item()}); lower the learning rate")
        loss.backward()
        optimizer.step()
        total += loss.item() * w
        weight += w
        bar.set_postfix(loss=f"{total / weight:.4g}")
    bar.close()
    return total / max(weight, 1e-12)


def _record(
    state: TrainingState,
    module: torch.nn.Module,
    train_loss: float,
    validation: float | None,
    lr: float,
    seconds: float,
    lr_step_down: bool,
) -> None:
    """Add an epoch to ``state``'s history, keep the weights when they are the best so far, and
    count a learning-rate step down when ``lr_step_down`` and the training loss rose."""
    history = state.history
    history.train_loss.append(train_loss)
    history.validation_loss.append(validation)
    history.learning_rate.append(lr)
    history.seconds.append(seconds)
    monitored = train_loss if validation is None else validation
    if monitored < state.best_loss:
        state.best_loss = monitored
        state.stale_epochs = 0
        history.best_epoch = state.epoch
        state.best_weights = {k: v.detach().clone() for k, v in module.state_dict().items()}
    else:
        state.stale_epochs += 1
    if lr_step_down and history.epochs > 1 and train_loss > history.train_loss[-2]:
        state.lr_steps += 1


def save_state(state: TrainingState, module: torch.nn.Module, folder: Path) -> None:
    """Write ``state`` and ``module``'s current weights into ``folder`` (JSON + safetensors)."""
    import torch
    from safetensors.torch import save as to_safetensors

    tensors = {f"last.{k}": v for k, v in module.state_dict().items()}
    tensors |= {f"best.{k}": v for k, v in (state.best_weights or {}).items()}
    optimizer_json = None
    if state.optimizer is not None:
        per_param: dict[str, dict[str, Any]] = {}
        for pid, values in state.optimizer["state"].items():
            per_param[str(pid)] = {}
            for key, value in values.items():
                if isinstance(value, torch.Tensor):
                    tensors[f"optimizer.{pid}.{key}"] = value
                else:
                    per_param[str(pid)][key] = value
        optimizer_json = {"state": per_param, "param_groups": state.optimizer["param_groups"]}
    if state.torch_rng is not None:
        tensors["rng.torch"] = state.torch_rng
    tensors = {k: v.detach().contiguous().clone() for k, v in tensors.items()}
    (folder / STATE_TENSORS).write_bytes(to_safetensors(tensors))
    info = {
        "history": state.history.to_dict(),
        "best_loss": state.best_loss if math.isfinite(state.best_loss) else None,
        "stale_epochs": state.stale_epochs,
        "lr_steps": state.lr_steps,
        "optimizer": optimizer_json,
        "numpy_rng": state.numpy_rng,
    }
    (folder / STATE_JSON).write_text(json.dumps(info, indent=1), encoding="utf-8")


def load_state(folder: Path, module: torch.nn.Module) -> TrainingState:
    """Read a state written by :func:`save_state`; load its last weights into ``module``."""
    from safetensors.torch import load_file

    try:
        info = json.loads((folder / STATE_JSON).read_text(encoding="utf-8"))
        tensors = load_file(folder / STATE_TENSORS)
    except (OSError, ValueError) as exc:
        raise VispeechError(f"cannot read the training state in {folder}: {exc}") from None
    module.load_state_dict({k[5:]: v for k, v in tensors.items() if k.startswith("last.")})
    optimizer = None
    if info["optimizer"] is not None:
        per_param: dict[int, dict] = {int(pid): dict(values) for pid, values in info["optimizer"]["state"].items()}
        for key, value in tensors.items():
            if key.startswith("optimizer."):
                _, pid, name = key.split(".", 2)
                per_param.setdefault(int(pid), {})[name] = value
        optimizer = {"state": per_param, "param_groups": info["optimizer"]["param_groups"]}
    best = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
    return TrainingState(
        history=TrainingHistory.from_dict(info["history"]),
        best_loss=math.inf if info["best_loss"] is None else info["best_loss"],
        stale_epochs=info["stale_epochs"],
        lr_steps=info["lr_steps"],
        best_weights=best or None,
        optimizer=optimizer,
        torch_rng=tensors.get("rng.torch"),
        numpy_rng=info["numpy_rng"],
    )


def sequence_loss(
    pred: torch.Tensor, target: torch.Tensor, motion_weight: float = 0.0, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """MSE over all values plus ``motion_weight`` x the thesis's motion term.

    ``pred`` and ``target`` are ``(batch, frames, channels)``; the motion term is the mean over
    frame transitions of the summed absolute difference of target and predicted deltas.
    ``mask`` (``(batch, frames)`` booleans) leaves out padding frames.
    """
    import torch

    if mask is None:
        mask = torch.ones(pred.shape[:2], dtype=torch.bool)
    m = mask.unsqueeze(-1).to(pred.dtype)
    loss = (((pred - target) ** 2) * m).sum() / (m.sum() * pred.shape[-1])
    if motion_weight and pred.shape[1] > 1:
        both = (mask[:, 1:] & mask[:, :-1]).unsqueeze(-1).to(pred.dtype)
        motion = ((target.diff(dim=1) - pred.diff(dim=1)).abs() * both).sum() / both.sum().clamp(min=1)
        loss = loss + motion_weight * motion
    return loss
