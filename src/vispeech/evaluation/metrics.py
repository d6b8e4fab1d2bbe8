"""Objective metrics of predicted against target curves (Beskow 2004, section 5).

Every function takes arrays of shape ``(frames, channels)`` and returns one value per
channel. Utterances are scored over their speech span only (:func:`speech_frames`):
leading and trailing silence is left out, as Beskow does.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Word
from vispeech.errors import VispeechError
from vispeech.limits import check_fps

SPEECH_MARGIN = 0.1
"""Seconds kept before the first word and after the last one in the speech span."""


def speech_frames(
    words: Sequence[Word], fps: float, n_frames: int, start_time: float = 0.0, margin: float = SPEECH_MARGIN
) -> np.ndarray:
    """Boolean mask of the frames in the speech span of an utterance.

    Frame k sits at ``start_time + k / fps`` seconds; the span runs from the first word's
    start minus ``margin`` to the last word's end plus ``margin`` (seconds), both ends
    included. Without words no frame is in the span.
    """
    mask = np.zeros(n_frames, dtype=bool)
    if not words:
        return mask
    times = start_time + np.arange(n_frames) / fps
    first, last = min(w.start for w in words), max(w.end for w in words)
    mask[(times >= first - margin - TIME_TOLERANCE) & (times <= last + margin + TIME_TOLERANCE)] = True
    return mask


def _pair(target: np.ndarray, predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    target, predicted = np.asarray(target, dtype=float), np.asarray(predicted, dtype=float)
    if target.ndim == 1:
        target, predicted = target[:, None], predicted.reshape(len(predicted), -1)
    if target.shape != predicted.shape or target.ndim != 2:
        raise VispeechError(f"target and prediction shapes differ: {target.shape} and {predicted.shape}")
    return target, predicted


def mse(target: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Mean squared error per channel (NaN for no frames)."""
    target, predicted = _pair(target, predicted)
    if not len(target):
        return np.full(target.shape[1], np.nan)
    return np.mean((predicted - target) ** 2, axis=0)


def value_range(targets: Sequence[np.ndarray]) -> np.ndarray:
    """Per channel, max minus min of the target over all frames of all ``targets`` arrays."""
    stacked = np.concatenate([np.asarray(t, dtype=float).reshape(len(t), -1) for t in targets])
    if not len(stacked):
        return np.full(stacked.shape[1], np.nan)
    return stacked.max(axis=0) - stacked.min(axis=0)


def rmse_percent(target: np.ndarray, predicted: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Root-mean-square error per channel as a percentage of ``span`` (the target's range;
    see :func:`value_range`). NaN where the range is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.asarray(span) > 0, 100.0 * np.sqrt(mse(target, predicted)) / span, np.nan)


def pearson_r(target: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Pearson product-moment correlation per channel; NaN where either curve is constant."""
    target, predicted = _pair(target, predicted)
    if len(target) < 2:
        return np.full(target.shape[1], np.nan)
    t = target - target.mean(axis=0)
    p = predicted - predicted.mean(axis=0)
    denominator = np.sqrt((t**2).sum(axis=0) * (p**2).sum(axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (t * p).sum(axis=0) / denominator
    return np.where(denominator > 1e-12, np.clip(r, -1.0, 1.0), np.nan)


@dataclass
class ChannelScores:
    """Scores per channel of one model on a set of utterances.

    ``mse``, ``rmse_percent`` and ``r`` pool the frames of every utterance (concatenated);
    the ``utterance_*`` arrays are means over utterances of the per-utterance scores
    (utterances where r is undefined are left out of ``utterance_r``). ``range`` is the
    target's range over all frames that ``rmse_percent`` divides by; ``frames`` and
    ``utterances`` count what was scored; ``per_utterance_rmse_percent`` and ``per_utterance_r``
    (utterances × channels) are each scored utterance's own, in order (for statistics over
    utterances, :mod:`vispeech.evaluation.statistics`).
    """

    channels: tuple[str, ...]
    mse: np.ndarray
    rmse_percent: np.ndarray
    r: np.ndarray
    utterance_mse: np.ndarray
    utterance_rmse_percent: np.ndarray
    utterance_r: np.ndarray
    range: np.ndarray
    frames: int
    utterances: int
    per_utterance_rmse_percent: np.ndarray
    per_utterance_r: np.ndarray

    def __getitem__(self, channel: str) -> dict[str, float]:
        """The scores of one channel as a dict."""
        try:
            j = self.channels.index(channel)
        except ValueError:
            raise VispeechError(f"no scores for channel {channel!r}") from None
        return {
            key: float(getattr(self, key)[j])
            for key in ("mse", "rmse_percent", "r", "utterance_mse", "utterance_rmse_percent", "utterance_r")
        }


def score_channels(
    channels: Sequence[str],
    targets: Sequence[np.ndarray],
    predictions: Sequence[np.ndarray],
    span: np.ndarray | None = None,
) -> ChannelScores:
    """Score per-utterance ``predictions`` against ``targets`` (lists of ``(frames, channels)``
    arrays holding only the frames to score, e.g. the speech span).

    ``span`` is the range RMSE is a percentage of; by default :func:`value_range` of
    ``targets``, i.e. the range over the whole set, the same for every utterance.
    """
    channels = tuple(channels)
    if len(targets) != len(predictions):
        raise VispeechError(f"{len(targets)} target arrays but {len(predictions)} predictions")
    pairs = [_pair(np.reshape(t, (len(t), -1)), np.reshape(p, (len(p), -1))) for t, p in zip(targets, predictions)]
    pairs = [(t, p) for t, p in pairs if len(t)]
    if not pairs:
        raise VispeechError("no frames to score")
    if pairs[0][0].shape[1] != len(channels):
        raise VispeechError(f"{len(channels)} channel names for {pairs[0][0].shape[1]} columns")
    span = value_range([t for t, _ in pairs]) if span is None else np.asarray(span, dtype=float)
    target = np.concatenate([t for t, _ in pairs])
    predicted = np.concatenate([p for _, p in pairs])
    per_utterance = np.array([[mse(t, p), rmse_percent(t, p, span), pearson_r(t, p)] for t, p in pairs])
    finite = np.isfinite(per_utterance)
    counts = finite.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, np.where(finite, per_utterance, 0.0).sum(axis=0) / counts, np.nan)
    return ChannelScores(
        channels=channels,
        mse=mse(target, predicted),
        rmse_percent=rmse_percent(target, predicted, span),
        r=pearson_r(target, predicted),
        utterance_mse=means[0],
        utterance_rmse_percent=means[1],
        utterance_r=means[2],
        range=span,
        frames=len(target),
        utterances=len(pairs),
        per_utterance_rmse_percent=per_utterance[:, 1],
        per_utterance_r=per_utterance[:, 2],
    )


def _rates(fps: float | Sequence[float], curves: Sequence[np.ndarray]) -> list[float]:
    """One frame rate per curve: ``fps`` for all, or ``fps[i]`` for curve i."""
    if np.ndim(fps) == 0:
        return [check_fps(cast(float, fps))] * len(curves)
    rates = cast(Sequence[float], fps)  # np.ndim told a scalar from a sequence (or an array) of rates
    if len(rates) != len(curves):
        raise VispeechError(f"{len(rates)} frame rates for {len(curves)} curves")
    return [check_fps(f) for f in rates]


def best_lag(
    targets: Sequence[np.ndarray],
    predictions: Sequence[np.ndarray],
    fps: float | Sequence[float],
    max_seconds: float = 0.2,
) -> float:
    """Seconds by which the predictions trail the targets where they correlate best (negative:
    they lead), from per-utterance 1-D arrays pooled: Pearson r of target frame t with predicted
    frame t + lag, for lags up to ``max_seconds`` either way.

    ``fps`` is the curves' frame rate, or one per utterance: lags are then tried in steps of
    the highest rate's frame, each utterance shifted by the whole frames of its own rate nearest
    the lag."""
    rates = _rates(fps, targets)
    step = 1.0 / max(rates)
    reach = int(round(max_seconds / step))
    best, best_r = 0, -np.inf
    for k in range(-reach, reach + 1):
        shifts = [int(round(k * step * rate)) for rate in rates]
        t = np.concatenate([x[max(0, -lag) : len(x) - max(0, lag)] for x, lag in zip(targets, shifts)])
        p = np.concatenate([y[max(0, lag) : len(y) - max(0, -lag)] for y, lag in zip(predictions, shifts)])
        if len(t) > 2 and np.std(t) > 0 and np.std(p) > 0:
            r = float(np.corrcoef(t, p)[0, 1])
            if r > best_r:
                best, best_r = k, r
    return best * step


HIGH_FREQUENCY = 8.0
"""Hz above which a curve's motion counts as jitter (speech articulation moves at 2–7 Hz)."""


def motion_profile(curves: Sequence[np.ndarray], fps: float | Sequence[float]) -> dict[str, float]:
    """How a channel moves, from per-utterance 1-D arrays at ``fps`` (one rate for all, or one
    per curve): the root mean square of its velocity, acceleration and jerk (units per second,
    per second², per second³), and the share of its energy (mean removed, per utterance, pooled)
    above :data:`HIGH_FREQUENCY` Hz. Jitter shows as more jerk and high-frequency energy than
    the recorded curve has, over-smoothing as less."""
    rates = _rates(fps, curves)
    out = {}
    for order, name in ((1, "velocity"), (2, "acceleration"), (3, "jerk")):
        steps = [np.diff(c, order) * rate**order for c, rate in zip(curves, rates) if len(c) > order]
        out[f"{name}_rms"] = float(np.sqrt(np.mean(np.concatenate(steps) ** 2))) if steps else float("nan")
    high = total = 0.0
    for c, rate in zip(curves, rates):
        if len(c) < 4:
            continue
        power = np.abs(np.fft.rfft(c - c.mean())) ** 2
        freqs = np.fft.rfftfreq(len(c), 1.0 / rate)
        high += float(power[freqs > HIGH_FREQUENCY].sum())
        total += float(power.sum())
    out["high_frequency_share"] = high / total if total > 0 else float("nan")
    return out


def lip_vertex_error(
    tracked_scores: Sequence[np.ndarray],
    predicted_scores: Sequence[np.ndarray],
    shapes: Sequence[np.ndarray],
    ridge: float = 1e-3,
) -> dict[str, float]:
    """The lip vertex error (the field's, Karras et al. / VOCA: per frame the largest distance of a
    lip vertex from its place, then the mean) in 2-D landmark space, for a model that predicts
    blend shapes.

    A linear read-out from the channels to the lip landmarks (``shapes``: per utterance frames ×
    landmarks × 3, e.g. :func:`vispeech.corpus.articulation.lip_shape`; x and y used) is fitted by
    ridge regression on the recording's own scores (``tracked_scores``, frames × channels), so it
    maps blend shapes to lips as the tracker relates them; the predictions go through it. Returns
    ``lve`` (the model's, in eye-corner distances), ``floor`` (the read-out's error on the
    recorded scores: what no model can go below this way) and ``aperture_mae`` (the mean absolute
    error of the inner-lip gap, landmarks 13 to 14, the first two)."""
    x = np.concatenate(tracked_scores)
    y = np.concatenate([s[:, :, :2].reshape(len(s), -1) for s in shapes])
    design = np.column_stack([x, np.ones(len(x))])
    weights = np.linalg.solve(design.T @ design + ridge * len(x) * np.eye(design.shape[1]), design.T @ y)
    truth = y.reshape(len(y), -1, 2)

    def read(scores: np.ndarray) -> np.ndarray:
        return (np.column_stack([scores, np.ones(len(scores))]) @ weights).reshape(len(scores), -1, 2)

    def errors(points: np.ndarray) -> tuple[float, float]:
        vertex = float(np.linalg.norm(points - truth, axis=2).max(axis=1).mean())
        gap = np.linalg.norm(points[:, 0] - points[:, 1], axis=1)
        return vertex, float(np.abs(gap - np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1)).mean())

    lve, aperture = errors(read(np.concatenate(predicted_scores)))
    floor, _ = errors(read(x))
    return {"lve": lve, "floor": floor, "aperture_mae": aperture}
