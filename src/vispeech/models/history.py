"""What a fit went through: per-epoch (or per-iteration) losses, rates and times."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class TrainingHistory:
    """Per-epoch losses, learning rates and seconds; ``best_epoch`` counts from 1 (0: none yet)."""

    train_loss: list[float] = field(default_factory=list)
    validation_loss: list[float | None] = field(default_factory=list)
    learning_rate: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    best_epoch: int = 0

    @property
    def epochs(self) -> int:
        return len(self.train_loss)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TrainingHistory:
        return cls(**{k: data[k] for k in ("train_loss", "validation_loss", "learning_rate", "seconds", "best_epoch")})

    def plot(self, path: str | Path) -> None:
        """Draw training and validation loss per epoch (log scale) into a PNG at ``path``."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        figure = Figure(figsize=(6, 4), dpi=100)
        FigureCanvasAgg(figure)
        axes = figure.add_subplot()
        epochs = np.arange(1, self.epochs + 1)
        axes.plot(epochs, self.train_loss, marker="o", markersize=3, label="training")
        validation = [np.nan if v is None else v for v in self.validation_loss]
        if not np.all(np.isnan(validation)):
            axes.plot(epochs, validation, marker="o", markersize=3, label="validation")
        if self.best_epoch:
            axes.axvline(self.best_epoch, color="grey", linestyle=":", label=f"best (epoch {self.best_epoch})")
        if self.epochs and min(self.train_loss) > 0:
            axes.set_yscale("log")
        axes.set_xlabel("epoch")
        axes.set_ylabel("loss")
        axes.legend()
        figure.tight_layout()
        figure.savefig(path, format="png")
