"""Least-squares fitting of the Cohen–Massaro and Öhman models to recorded tracks.

Beskow (2004, §4) fits each output channel separately ("ten separate estimation problems"):
the parameters of one channel minimise the squared error Σ (z − y)² between the model's
curve z and the recorded curve y over every frame of every training utterance. The
parameters are tied per phone symbol: all segments of one phone share them, so a column of
the Jacobian sums the derivatives of every segment of that phone. Stress is ignored (the
corpus aligner gives none, and the per-phone spec format has no stress key).

:func:`levenberg_marquardt` solves every channel's problem with damped Gauss–Newton steps
``(JᵀJ + λ·diag JᵀJ) δ = −Jᵀr`` from analytic Jacobians, under box bounds (variables at a
bound whose gradient points outward are held there for the step; the step is clipped to
the box), and stops each channel early once its validation error has not improved for
``patience`` iterations, keeping the best parameters. The models supply the Jacobians; this
module gathers the frames, ties the phones and poses and solves each channel's problem
(:func:`fit_channels`); the models turn the fitted values into their learned per-row tables
(``tables_``), leaving their hyper-parameters as they were.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import cast

import numpy as np

from vispeech.errors import VispeechError
from vispeech.models.fitting import show_progress, training_split
from vispeech.models.history import TrainingHistory
from vispeech.models.rules.segments import Segments
from vispeech.phonetics.features import phone_rows

TOLERANCE = 1e-4
"""A channel has converged when an accepted step lowers its squared error by less than this fraction."""

_MAX_TRIES = 12
_DAMPING_START, _DAMPING_MIN, _DAMPING_MAX = 1e-3, 1e-9, 1e9


@dataclass(frozen=True)
class Recording:
    """One utterance laid out for fitting.

    ``segments`` are the model's gap-filled segments with ``times`` replaced by the times
    (seconds) of the recorded frames that lie within the phones and were tracked;
    ``values`` (frames × fitted channels) are the recorded values there.
    """

    segments: Segments
    values: np.ndarray

    @property
    def own_rows(self) -> np.ndarray:
        """For each frame, the phone row of the segment it falls in."""
        seg = self.segments
        own = np.minimum(np.searchsorted(seg.ends, seg.times, side="right"), len(seg.rows) - 1)
        return seg.rows[own]


@dataclass(frozen=True)
class FitData:
    """What a fit runs on: the language, the fitted channels, training and validation recordings."""

    language: str
    channels: tuple[str, ...]
    train: list[Recording]
    validation: list[Recording]

    @classmethod
    def gather(cls, model, corpus, channels: Sequence[str] | None) -> FitData:
        """Lay out ``corpus`` (see :func:`~vispeech.models.fitting.training_split`) for ``model``
        (a :class:`~vispeech.models.rules.phone_targets.PhoneTargetModel`); ``channels``
        default to the model's channels that every training track has."""
        train_set, held_out = training_split(corpus)
        language = train_set[0].phones.language
        if any(u.phones.language != language for u in train_set + held_out):
            raise VispeechError("cannot fit on utterances of more than one language")
        if channels is None:
            channels = tuple(c for c in model.channels if all(c in u.track.channels for u in train_set))
            if not channels:
                raise VispeechError(f"the corpus tracks have none of the {model.family} model's channels")
        else:
            channels = tuple(dict.fromkeys([channels] if isinstance(channels, str) else channels))
            unknown = [c for c in channels if c not in model.channels]
            if unknown or not channels:
                named = ", ".join(unknown) or "(none given)"
                raise VispeechError(f"model {model.family} does not predict channels {named}")
        train = [_recording(model, u, channels) for u in train_set]
        if not any(len(r.values) for r in train):
            raise VispeechError("the training utterances have no tracked frames within their phones")
        return cls(language, channels, train, [_recording(model, u, channels) for u in held_out])


def _recording(model, utterance, channels: tuple[str, ...]) -> Recording:
    track = utterance.track
    missing = [c for c in channels if c not in track.channels]
    if missing:
        raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} lacks channels {', '.join(missing)}")
    seg = model.segments(utterance.phones, track.fps)
    times = track.times
    keep = (times >= 0.0) & (times < utterance.phones.duration)
    mask = getattr(utterance, "frame_mask", None)
    if mask is not None:
        keep &= np.asarray(mask, dtype=bool)
    values = track.values[:, [track.index(c) for c in channels]][keep]
    return Recording(replace(seg, times=times[keep]), values)


@dataclass(frozen=True)
class PhoneTying:
    """Fitted parameters tied per phone symbol.

    ``symbols`` are the fitted ones (those the training segments use, in inventory order);
    ``column[row]`` is, for each row of :func:`~vispeech.targets.tables.phone_rows`, the
    position of its symbol in ``symbols``, or -1 where the symbol is not fitted.
    """

    language: str
    symbols: tuple[str, ...]
    column: np.ndarray

    @classmethod
    def of(cls, language: str, recordings: Iterable[Recording], rows: np.ndarray | None = None) -> PhoneTying:
        """The symbols of the segments of ``recordings`` (only those with ``rows[row]`` True if given)."""
        table = phone_rows(language)
        used = np.zeros(len(table.symbols), dtype=bool)
        for recording in recordings:
            used[recording.segments.rows] = True
        if rows is not None:
            used &= rows
        seen = {table.symbols[r] for r in np.flatnonzero(used)}
        symbols = tuple(dict.fromkeys(s for s in table.symbols if s in seen))
        position = {s: i for i, s in enumerate(symbols)}
        column = np.array([position.get(s, -1) for s in table.symbols], dtype=np.intp)
        return cls(language, symbols, column)

    def __len__(self) -> int:
        return len(self.symbols)

    @property
    def first_rows(self) -> np.ndarray:
        """The unstressed row of each fitted symbol (where its starting values are read)."""
        keys = phone_rows(self.language).keys
        return np.array([keys[s, False] for s in self.symbols], dtype=np.intp)

    def expand(self, base: np.ndarray, fitted: np.ndarray) -> np.ndarray:
        """A per-row table: ``base`` with the rows of fitted symbols set to their ``fitted`` value."""
        out = base.copy()
        tied = self.column >= 0
        out[tied] = fitted[self.column[tied]]
        return out

    def columns(self, rows: np.ndarray, offset: int = 0) -> np.ndarray:
        """Jacobian columns of phone ``rows`` (``offset`` + symbol position; -1 where not fitted)."""
        column = self.column[rows]
        return np.where(column >= 0, column + offset, -1)

    def frame_means(self, recordings: Sequence[Recording], fallback: np.ndarray) -> np.ndarray:
        """Mean recorded value (symbols × channels) over the frames inside each symbol's
        segments; ``fallback[symbol]`` where a symbol owns no frame."""
        n = len(self.symbols)
        columns = np.concatenate([self.column[r.own_rows] for r in recordings])
        values = np.concatenate([r.values for r in recordings])
        fitted = columns >= 0
        columns, values = columns[fitted], values[fitted]
        counts = np.bincount(columns, minlength=n)[:n]
        out = np.array(fallback, dtype=float, copy=True)
        for j in range(values.shape[1]):
            sums = np.bincount(columns, weights=values[:, j], minlength=n)[:n]
            out[counts > 0, j] = sums[counts > 0] / counts[counts > 0]
        return out


def scatter_jacobian(n_frames: int, n_params: int, parts: Iterable[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The dense Jacobian (``n_frames`` × ``n_params``) as sums of per-frame derivatives.

    Each part is ``(columns, values)`` of shape ``(n_frames, ...)``: frame f adds
    ``values[f, ...]`` to its columns ``columns[f, ...]`` (negative ones are skipped).
    """
    flat, weights = [], []
    for columns, values in parts:
        columns = np.asarray(columns)
        frames = np.arange(n_frames).reshape((n_frames,) + (1,) * (columns.ndim - 1))
        used = columns >= 0
        flat.append((frames * n_params + columns)[used])
        weights.append(np.broadcast_to(values, columns.shape)[used])
    size = n_frames * n_params
    sums = np.bincount(np.concatenate(flat), weights=np.concatenate(weights), minlength=size)
    return sums.reshape(n_frames, n_params)


@dataclass(frozen=True)
class ChannelProblem:
    """One channel's box-bounded least-squares problem.

    ``residuals(x, jacobian)`` gives the training residuals z − y and, when ``jacobian``, their
    Jacobian (frames × parameters; else None); ``validation`` does the same on the validation
    frames, or is None when there is nothing to validate on.
    """

    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    residuals: Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]]
    validation: Callable[[np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]] | None = None


class _Channel:
    """The running state of one channel's fit."""

    def __init__(self, problem: ChannelProblem):
        self.problem = problem
        self.x = np.clip(problem.x0, problem.lower, problem.upper)
        r, _ = problem.residuals(self.x, False)
        self.n_frames = max(len(r), 1)
        self.sse = float(r @ r)
        self.damping = _DAMPING_START
        self.nu = 2.0
        self.best_x, self.best_train = self.x, self.sse / self.n_frames
        self.best_validation = self._validation_mse()
        self.stale = 0
        self.active = True

    def _validation_mse(self) -> float | None:
        if self.problem.validation is None:
            return None
        r, _ = self.problem.validation(self.x, False)
        return float(r @ r) / len(r) if len(r) else None

    def iterate(self, patience: int) -> bool:
        """One accepted Levenberg–Marquardt step, then early stopping; True if the kept parameters changed."""
        p = self.problem
        r, jacobian = p.residuals(self.x, True)
        assert jacobian is not None  # asked for
        gradient = jacobian.T @ r
        normal = jacobian.T @ jacobian
        scale = np.diag(normal).copy()
        scale = np.maximum(scale, 1e-9 * max(float(scale.max()), 1e-300))
        held = ((self.x <= p.lower) & (gradient > 0)) | ((self.x >= p.upper) & (gradient < 0))
        free = np.flatnonzero(~held)
        accepted = None
        for _ in range(_MAX_TRIES):
            system = normal[np.ix_(free, free)] + self.damping * np.diag(scale[free])
            try:
                step = np.linalg.solve(system, -gradient[free])
            except np.linalg.LinAlgError:
                step = None
            if step is not None and np.all(np.isfinite(step)):
                x = self.x.copy()
                x[free] += step
                x = np.clip(x, p.lower, p.upper)
                trial, _ = p.residuals(x, False)
                sse = float(trial @ trial)
                if sse < self.sse:
                    accepted = x, sse
                    delta = x - self.x
                    predicted = -(2 * gradient @ delta + delta @ normal @ delta)
                    rho = (self.sse - sse) / predicted if predicted > 0 else 0.0
                    self.damping = max(self.damping * max(1 / 3, 1 - (2 * rho - 1) ** 3), _DAMPING_MIN)
                    self.nu = 2.0
                    break
            self.damping = min(self.damping * self.nu, _DAMPING_MAX)
            self.nu *= 2
        if accepted is None:
            self.active = False
            return False
        x, sse = accepted
        converged = self.sse - sse <= TOLERANCE * self.sse
        self.x, self.sse = x, sse
        if converged:
            self.active = False
        validation = self._validation_mse()
        if validation is None or self.best_validation is None or validation < self.best_validation:
            self.best_x, self.best_train, self.best_validation = self.x, self.sse / self.n_frames, validation
            self.stale = 0
            return True
        self.stale += 1
        if self.stale >= patience:
            self.active = False
        return False


def levenberg_marquardt(
    problems: Mapping[str, ChannelProblem],
    *,
    max_iterations: int,
    patience: int,
    progress: bool = True,
) -> tuple[dict[str, np.ndarray], TrainingHistory]:
    """Fit every channel's problem; returns the kept parameters per channel and the history.

    The channels step in lockstep: one iteration makes one accepted step on every channel
    still running. A channel stops when its validation error has not improved for
    ``patience`` iterations (it keeps the parameters of its best one), when it has converged
    (see :data:`TOLERANCE`), when no damping gives a better step, or after
    ``max_iterations``. History entry k holds the mean over channels of the training and
    validation MSE of the parameters kept after iteration k, the geometric mean damping λ
    of the running channels (as ``learning_rate``) and the seconds taken; ``best_epoch`` is
    the last iteration that changed any channel's kept parameters.
    """
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 0:
        raise VispeechError(f"max_iterations must be a whole number >= 0, got {max_iterations!r}")
    if isinstance(patience, bool) or not isinstance(patience, int) or patience < 1:
        raise VispeechError(f"patience must be a whole number >= 1, got {patience!r}")
    write = _writer(progress)
    states = {name: _Channel(problem) for name, problem in problems.items()}
    history = TrainingHistory()
    write(f"start: {_summary(states.values())}")
    for iteration in range(1, max_iterations + 1):
        running = [s for s in states.values() if s.active]
        if not running:
            break
        started = time.perf_counter()
        damping = math.exp(float(np.mean([math.log(s.damping) for s in running])))
        changed = [s.iterate(patience) for s in running]
        train, validation = _mean_losses(states.values())
        history.train_loss.append(train)
        history.validation_loss.append(validation)
        history.learning_rate.append(damping)
        history.seconds.append(time.perf_counter() - started)
        if any(changed):
            history.best_epoch = iteration
        write(f"iteration {iteration}: {_summary(states.values())}, {history.seconds[-1]:.1f} s")
    return {name: s.best_x for name, s in states.items()}, history


def _writer(progress: bool) -> Callable[[str], None]:
    """A function printing one progress line to stderr, or doing nothing."""
    import sys

    if not progress:
        return lambda line: None
    return lambda line: print(line, file=sys.stderr, flush=True)


def _mean_losses(states: Iterable[_Channel]) -> tuple[float, float | None]:
    states = list(states)
    train = float(np.mean([s.best_train for s in states]))
    held = [s.best_validation for s in states]
    return train, (None if any(v is None for v in held) else float(np.mean(cast(list[float], held))))


def _summary(states: Iterable[_Channel]) -> str:
    states = list(states)
    train, validation = _mean_losses(states)
    shown = "" if validation is None else f", validation MSE {validation:.4g}"
    return f"training MSE {train:.4g}{shown} ({sum(s.active for s in states)}/{len(states)} channels running)"


def fit_channels(
    model,
    data: FitData,
    start: Callable[[int, int], tuple[tuple, np.ndarray]],
    lower: np.ndarray,
    upper: np.ndarray,
    train,
    held,
    progress: bool | None,
) -> dict[str, np.ndarray]:
    """Solve each fitted channel's least-squares problem for ``model`` (a Cohen–Massaro or Öhman
    model) with its ``max_iterations`` and ``patience``; returns the parameters per channel.

    ``start(j, m)`` gives the per-row base tables and the starting parameters of fitted channel
    j (column m of the model's channels); ``train`` and ``held`` (or ``None``) are the designs
    whose ``residuals(base, j, x, jacobian)`` are minimised and validated. Sets the model's
    ``fitted_channels_`` and ``history_``.
    """
    problems = {}
    for j, channel in enumerate(data.channels):
        base, x0 = start(j, model.channels.index(channel))
        problems[channel] = ChannelProblem(
            x0,
            lower,
            upper,
            partial(train.residuals, base, j),
            None if held is None else partial(held.residuals, base, j),
        )
    params = model.get_params()
    fitted, model.history_ = levenberg_marquardt(
        problems, max_iterations=params["max_iterations"], patience=params["patience"], progress=show_progress(progress)
    )
    model.fitted_channels_ = data.channels
    return fitted
