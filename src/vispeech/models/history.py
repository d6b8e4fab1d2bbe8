"""What a fit went through: per-epoch (or per-iteration) losses, rates and times."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field


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
