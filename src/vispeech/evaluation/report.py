"""Evaluating control models on a corpus: metrics and closures per model, as text or Markdown.

:func:`evaluate_models` animates every utterance with each model at the frame rate of its
recorded track (:func:`vispeech.pipeline.animate`, optionally post-processed), scores the channels over
the speech span of each utterance (:func:`vispeech.evaluation.metrics.speech_frames`;
frames the tracker missed are left out) and counts lip closures
(:mod:`vispeech.evaluation.closures`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, PhoneSequence
from vispeech.corpus.articulation import LIP_LANDMARKS, articulatory_parameters, lip_shape
from vispeech.corpus.corpus import Corpus, Utterance, frame_rates_text, recorded_track
from vispeech.errors import VispeechError
from vispeech.evaluation.closures import (
    BILABIAL_RATE_TARGET,
    CLOSED_SHARE_TOLERANCE,
    MODEL_CLOSED,
    PHONE_CLASSES,
    TRACKED_CLOSED,
    ClosureCounts,
    count_closures,
    frame_classes,
    lip_opening,
    model_closed,
    tracked_closed,
)
from vispeech.evaluation.metrics import (
    SPEECH_MARGIN,
    ChannelScores,
    best_lag,
    lip_vertex_error,
    motion_profile,
    score_channels,
    speech_frames,
)
from vispeech.frontends.audio import AudioClip
from vispeech.models.contract import Estimator
from vispeech.motion.arkit import ARTICULATORY_CHANNELS, MOUTH_CHANNELS
from vispeech.motion.track import Track

EVALUATED_CHANNELS: tuple[str, ...] = MOUTH_CHANNELS + ARTICULATORY_CHANNELS
"""Channels scored by default (those of them a model predicts and the corpus has): the ARKit
mouth/jaw set and the articulatory parameters."""


@dataclass
class ModelEvaluation:
    """One model's results: channel scores and (when the corpus has landmarks) closure counts."""

    label: str
    model: str
    scores: ChannelScores
    closures: ClosureCounts | None
    dynamics: dict[str, float] | None = None
    """jawOpen's motion (:func:`~vispeech.evaluation.metrics.motion_profile`) and ``lag_s``
    (:func:`~vispeech.evaluation.metrics.best_lag`), when the model predicts it and the corpus has it."""
    lips: dict[str, float] | None = None
    """The lip vertex error in landmark space and its floor (:func:`~vispeech.evaluation.metrics.lip_vertex_error`),
    when the corpus has lip landmarks."""
    by_phone: dict[str, float] | None = None
    """jawOpen's RMSE (% of its range) over the scored frames of each phone class
    (:data:`~vispeech.evaluation.closures.PHONE_CLASSES`; NaN for a class with no frames)."""


@dataclass
class Evaluation:
    """Results of :func:`evaluate_models` for several models on one set of utterances."""

    corpus: str
    frame_rates: tuple[float, ...]
    """The frame rates of the utterances' tracks (:attr:`~vispeech.corpus.corpus.Corpus.frame_rates`):
    each utterance is animated and scored at its own."""
    utterances: int
    postprocessing: str
    """How the predictions were post-processed: ``auto``, ``none`` or a preset's name."""
    models: list[ModelEvaluation]
    utterance_ids: list[str] | None = None
    """The scored utterances, in the order of the per-utterance scores."""
    recorded_dynamics: dict[str, float] | None = None
    """The recorded jawOpen's motion, to compare the models' with."""
    sync: str | None = None
    """The model whose lags re-synced the predictions (:func:`evaluate_models`'s ``sync``), if any."""
    lags: dict[str, float] | None = None
    """With ``sync``: per utterance id, the seconds by which every model's predictions were moved
    earlier (negative: later) before scoring."""

    def __getitem__(self, label: str) -> ModelEvaluation:
        for result in self.models:
            if result.label == label:
                return result
        raise VispeechError(f"no results for model {label!r}")

    def metric_rows(self) -> list[list[str]]:
        """Rows of the metrics table: model, channel, MSE, RMSE %, r, and the utterance means
        of RMSE % and r; each model ends with the mean over its channels."""
        rows = []
        for result in self.models:
            s = result.scores
            for j, channel in enumerate(s.channels):
                rows.append(
                    [
                        result.label,
                        channel,
                        *_numbers(s.mse[j], s.rmse_percent[j], s.r[j], s.utterance_rmse_percent[j], s.utterance_r[j]),
                    ]
                )
            if len(s.channels) > 1:
                means = [
                    np.nanmean(a) if np.isfinite(a).any() else np.nan
                    for a in (s.mse, s.rmse_percent, s.r, s.utterance_rmse_percent, s.utterance_r)
                ]
                rows.append([result.label, "(mean)", *_numbers(*means)])
        return rows

    def closure_rows(self) -> list[list[str]]:
        """Rows of the closure table, one per model with closure counts."""
        rows = []
        for result in self.models:
            c = result.closures
            if c is None:
                continue
            rows.append(
                [
                    result.label,
                    f"{c.model_closures}/{c.tracked_closures}",
                    _fixed(c.bilabial_rate, 1),
                    _fixed(c.model_closed_share, 1),
                    _fixed(c.tracked_closed_share, 1),
                    _fixed(c.model_closed_share - c.tracked_closed_share, 1, signed=True),
                    "yes" if c.passed else "no",
                ]
            )
        return rows

    def _header(self) -> str:
        frames = self.models[0].scores.frames if self.models else 0
        return (
            f"{self.corpus}: {self.utterances} utterances, {frames} speech frames at "
            f"{frame_rates_text(self.frame_rates)} fps, "
            f"post-processing {self.postprocessing}" + (f", {self.sync_summary()}" if self.sync else "")
        )

    def sync_summary(self) -> str:
        """How the predictions were re-synced (``sync``), in words; ``""`` when they were not."""
        if self.sync is None or self.lags is None:
            return ""
        ms = np.array(list(self.lags.values())) * 1000
        return (
            f"re-synced by {self.sync}: predictions moved by each utterance's lag (median {np.median(ms):+.0f} ms, "
            f"{ms.min():+.0f} to {ms.max():+.0f} ms; {int((ms != 0).sum())} of {len(ms)} moved)"
        )

    def to_text(self) -> str:
        """The tables as aligned plain text."""
        parts = [self._header(), "", _text_table(_METRIC_COLUMNS, self.metric_rows())]
        closures = self.closure_rows()
        if closures:
            parts += ["", _text_table(_CLOSURE_COLUMNS, closures)]
        return "\n".join(parts) + "\n"

    def to_markdown(self) -> str:
        """The tables as Markdown, with a note on how each figure is computed."""
        parts = [
            "# Objective evaluation",
            "",
            self._header() + ".",
            "",
            f"Frames from {SPEECH_MARGIN:g} s before the first word to {SPEECH_MARGIN:g} s after the last, "
            "without untracked frames. MSE and Pearson r pool the frames of all utterances; RMSE % is "
            "the root-mean-square error as a percentage of the target's range over the whole set; "
            "the (utt.) columns are means over utterances of per-utterance values.",
            "",
            _markdown_table(_METRIC_COLUMNS, self.metric_rows()),
        ]
        closures = self.closure_rows()
        if closures:
            parts += [
                "",
                "## Lip closures",
                "",
                f"Tracked lips are closed where the inner-lip gap over the eye-corner distance is at most "
                f"{TRACKED_CLOSED:g}; a model's where jawOpen − mouthClose (or lip_aperture) is at most "
                f"{MODEL_CLOSED:.0%} of its utterance maximum. /p b m/: of the bilabials on which the tracked "
                f"lips close (phone ± 1 frame), those the model closes on too (target ≥ "
                f"{BILABIAL_RATE_TARGET:g} %); closed frames: share of speech frames with closed lips "
                f"(within {CLOSED_SHARE_TOLERANCE:g} points of the tracked share).",
                "",
                _markdown_table(_CLOSURE_COLUMNS, closures),
            ]
        return "\n".join(parts) + "\n"


_METRIC_COLUMNS = ("model", "channel", "MSE", "RMSE %", "r", "RMSE % (utt.)", "r (utt.)")
_CLOSURE_COLUMNS = ("model", "/p b m/ closed", "%", "closed frames %", "tracked %", "difference", "pass")


def _fixed(value: float, digits: int, signed: bool = False) -> str:
    if not math.isfinite(value):
        return "n/a"
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def _numbers(mse: float, rmse: float, r: float, utterance_rmse: float, utterance_r: float) -> list[str]:
    return [
        "n/a" if not math.isfinite(mse) else f"{mse:.5f}",
        _fixed(rmse, 2),
        _fixed(r, 3),
        _fixed(utterance_rmse, 2),
        _fixed(utterance_r, 3),
    ]


def _text_table(columns: Sequence[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(x)) for x in column) for column in zip(columns, *rows)]
    lines = [
        "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
        for row in [list(columns), *rows]
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines)


def _markdown_table(columns: Sequence[str], rows: list[list[str]]) -> str:
    rule = "|" + "|".join("---" if i < 2 else "---:" for i in range(len(columns))) + "|"
    lines = ["| " + " | ".join(columns) + " |", rule]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def available_channels(corpus: Corpus) -> tuple[str, ...]:
    """Channels the corpus gives targets for: its track channels and, when every utterance
    has landmarks, the articulatory parameters."""
    landmarks = len(corpus) > 0 and all(u.landmarks is not None for u in corpus)
    return tuple(corpus.channels) + (ARTICULATORY_CHANNELS if landmarks else ())


def model_channels(model: Estimator, corpus: Corpus, channels: Iterable[str] | None = None) -> tuple[str, ...]:
    """The channels to score a model on: ``channels`` (default: those of
    :data:`EVALUATED_CHANNELS` that the model predicts and the corpus has), with ``jawOpen``
    first whenever both have it."""
    available = available_channels(corpus)
    if channels is None:
        chosen = [c for c in EVALUATED_CHANNELS if c in model.channels and c in available]
        if not chosen:
            raise VispeechError(f"model {model.name} and corpus {corpus.name} share no mouth or jaw channel")
    else:
        chosen = list(dict.fromkeys(channels))
        if not chosen:  # not "the default": say so rather than score jawOpen alone
            raise VispeechError("no channels to score: name one or more, or leave channels out for the default")
        for channel in chosen:
            if channel not in available:
                raise VispeechError(f"corpus {corpus.name} has no channel {channel!r} to score")
            if channel not in model.channels:
                raise VispeechError(f"model {model.name} does not predict channel {channel!r}")
    if "jawOpen" in model.channels and "jawOpen" in available:
        chosen = ["jawOpen", *(c for c in chosen if c != "jawOpen")]
    return tuple(chosen)


def target_track(utterance: Utterance, channels: Sequence[str]) -> Track:
    """The utterance's recorded curves of ``channels``: track channels as they are,
    articulatory ones measured on its landmarks."""
    assert utterance.track is not None  # a corpus utterance: its recorded track
    values = np.empty((utterance.track.n_frames, len(channels)))
    measured = None
    for j, channel in enumerate(channels):
        if channel in utterance.track.channels:
            values[:, j] = utterance.track[channel]
        elif channel in ARTICULATORY_CHANNELS:
            if measured is None:
                measured = articulatory_parameters(utterance)
            values[:, j] = measured[channel]
        else:
            raise VispeechError(f"utterance {utterance.id} has no channel {channel!r}")
    return Track(values, tuple(channels), utterance.track.fps, utterance.track.start_time)


def predict_on_frames(
    model: Estimator, utterance: Utterance, postprocessing: str = "auto", transcript: bool = False, lag: int = 0
) -> Track:
    """The model's animation of the utterance on the frames of its recorded track: of its
    phones for a phone model, of its audio for an audio model, alone or (``transcript``) with
    its phones as ``vispeech animate --text`` gives them (:func:`vispeech.pipeline.animate_audio`).

    The model predicts at the track's frame rate from time 0, post-processed by
    ``postprocessing`` (:data:`vispeech.postprocess.Postprocessing`) when the output has
    ``jawOpen``; the result is sampled at the track's
    frame times, held at its first/last value beyond its ends; with ``lag``, moved that many
    frames earlier (frame t shows frame t + ``lag``; negative: later), as
    :func:`evaluate_models`'s ``sync`` moves it.
    """
    from vispeech.pipeline import animate, animate_audio

    assert utterance.track is not None  # a corpus utterance: its recorded track
    fps = utterance.track.fps
    postprocess = postprocessing if "jawOpen" in model.channels else "none"
    if model.input_kind == "audio":
        clip = AudioClip.from_array(*utterance.load_audio(), where=f"audio of {utterance.id}")
        predicted = animate_audio(clip, model, fps, postprocess, _phones(utterance) if transcript else None)
    else:
        predicted = animate(_phones(utterance), model, fps, postprocess)
    times = utterance.track.times
    if predicted.n_frames != len(times) or abs(predicted.start_time - times[0]) >= TIME_TOLERANCE:
        values = np.column_stack(
            [np.interp(times, predicted.times, predicted.values[:, j]) for j in range(len(predicted.channels))]
        )
        predicted = Track(values, predicted.channels, fps, float(times[0]))
    if lag:
        source = np.clip(np.arange(predicted.n_frames) + lag, 0, predicted.n_frames - 1)
        predicted = Track(predicted.values[source], predicted.channels, fps, predicted.start_time)
    return predicted


def _phones(utterance: Utterance) -> PhoneSequence:
    """The utterance's phones; :class:`VispeechError` when it has none."""
    if utterance.phones is None:
        raise VispeechError(f"utterance {utterance.id} has no phones: align the corpus first")
    return utterance.phones


def scored_frames(utterance: Utterance) -> np.ndarray:
    """Mask of the frames scored: the speech span (the corpus's word timings, else the
    aligned words) without frames the tracker missed."""
    track = recorded_track(utterance)
    words = utterance.words or (utterance.phones.words if utterance.phones is not None else [])
    mask = speech_frames(words, track.fps, track.n_frames, track.start_time)
    if utterance.frame_mask is not None:
        mask &= np.asarray(utterance.frame_mask, dtype=bool)
    return mask


def evaluate_models(
    corpus: Corpus,
    models: Mapping[str, Estimator],
    *,
    channels: Iterable[str] | None = None,
    postprocessing: str = "auto",
    transcript: bool = False,
    sync: Estimator | None = None,
    progress: bool = False,
) -> Evaluation:
    """Score each model (by label) on every utterance of ``corpus`` (e.g. ``corpus.split("test")``).

    ``channels`` as in :func:`model_channels`; ``postprocessing`` and ``transcript`` (audio models
    given the phones too) as in :func:`predict_on_frames`. ``sync``, a model with ``jawOpen``,
    re-syncs recordings whose picture and sound are out of step (web video's often are): per
    utterance, the whole frames within :data:`SYNC_REACH` at which its jawOpen agrees best with
    the recording's (:func:`~vispeech.evaluation.metrics.best_lag`; none at its edge, none under
    :data:`SYNC_MIN_SECONDS` of speech) are the utterance's lag, and
    every model's predictions are moved by it before scoring (:attr:`Evaluation.lags`). A lag
    chosen per utterance flatters: the figures that compare with others' are those without.
    Closure counts need utterances with face
    landmarks and a model output with ``jawOpen`` or ``lip_aperture``; otherwise a model's
    ``closures`` is ``None``. Raises :class:`VispeechError` for an empty corpus or an
    utterance without phones.
    """
    from tqdm.auto import tqdm

    if not len(corpus):
        raise VispeechError(f"corpus {corpus.name} has no utterances to evaluate")
    if not models:
        raise VispeechError("no model to evaluate")
    requested = None if channels is None else list(channels)
    plans = {label: model_channels(model, corpus, requested) for label, model in models.items()}
    reference = _reference(corpus, tuple(dict.fromkeys(c for chosen in plans.values() for c in chosen)))
    results = []
    bar = tqdm(
        total=(len(models) + (sync is not None)) * len(corpus), desc="evaluating", unit="utt", disable=not progress
    )
    try:
        lags = None if sync is None else _sync_lags(sync, corpus, reference.masks, postprocessing, bar.update)
        if lags is not None:  # the per-phone-class errors on the phones moved with the predictions
            reference.classes = _phone_classes(corpus, reference.masks, lags)
        for label, model in models.items():
            results.append(
                _evaluate_model(
                    label, model, plans[label], corpus, reference, (postprocessing, transcript), lags, bar.update
                )
            )
    finally:
        bar.close()
    ids = [u.id for u, mask in zip(corpus, reference.masks) if mask.any()]
    seconds = None if lags is None else {u.id: lag / recorded_track(u).fps for u, lag in zip(corpus, lags)}
    return Evaluation(
        corpus.name,
        corpus.frame_rates,
        len(corpus),
        postprocessing,
        results,
        ids,
        reference.dynamics,
        None if sync is None else sync.name,
        seconds,
    )


SYNC_REACH = 0.3
"""Seconds either way within which :func:`evaluate_models`'s ``sync`` looks for an utterance's lag."""
SYNC_MIN_SECONDS = 6.0
"""The shortest speech span (s) whose lag ``sync`` tells; shorter utterances keep theirs (0). On
stretches of grid_s1's validation split (25 fps) with the picture moved by 0, ±2 or ±4 frames,
``grid-tdnn``'s lag on the aligned phones was two frames or more off on 4 % of 3-s stretches,
2 % of 6-s ones and none of 33 9-s ones (one frame off: 34 %, 22 %, 12 %)."""


def _sync_lags(
    model: Estimator, corpus: Corpus, masks: list[np.ndarray], postprocessing: str, advance: Callable[[int], object]
) -> list[int]:
    """Per utterance, the frames by which ``model``'s jawOpen trails the recording's where they
    agree best over the scored frames (0 for fewer than :data:`SYNC_MIN_SECONDS` of them, or
    where the best is at the edge of :data:`SYNC_REACH`: no peak within it)."""
    if "jawOpen" not in model.channels:
        raise VispeechError(f"model {model.name} has no jawOpen to re-sync the recordings with")
    lags = []
    for utterance, mask in zip(corpus, masks):
        fps, lag = recorded_track(utterance).fps, 0
        if mask.sum() >= SYNC_MIN_SECONDS * fps:
            recorded = target_track(utterance, ["jawOpen"]).values[mask, 0]
            predicted = predict_on_frames(model, utterance, postprocessing).select(["jawOpen"]).values[mask, 0]
            lag = round(best_lag([recorded], [predicted], fps, SYNC_REACH) * fps)
        lags.append(lag if abs(lag) < round(SYNC_REACH * fps) else 0)  # at the edge: no peak within reach
        advance(1)
    return lags


@dataclass
class _Reference:
    """What every model is scored against: per utterance the scored frames, the recorded track
    of the channels ``needed`` and the tracked lip closures (None without lip landmarks); the
    lip shapes of the scored frames (None unless every utterance has them) and the phone class
    of each; and over the utterances with frames scored, their frame rates, recorded jawOpen and
    its motion (None unless jawOpen is needed)."""

    needed: tuple[str, ...]
    masks: list[np.ndarray]
    targets: list[Track]
    closed: list[np.ndarray | None]
    shapes: list[np.ndarray] | None
    classes: np.ndarray
    rates: list[float]
    jaw: list[np.ndarray] | None
    dynamics: dict[str, float] | None


def _reference(corpus: Corpus, needed: tuple[str, ...]) -> _Reference:
    """What the models are scored against on ``corpus``, for the channels ``needed``."""
    masks = [scored_frames(u) for u in corpus]
    targets = [target_track(u, needed) for u in corpus]
    closed = [tracked_closed(_landmarks(u)) if _has_lip_landmarks(u) else None for u in corpus]
    shapes = None
    if all(u.landmarks is not None and all(f"lm{k}" in u.landmarks for k in (1, 10, *LIP_LANDMARKS)) for u in corpus):
        shapes = [lip_shape(_landmarks(u))[mask] for u, mask in zip(corpus, masks)]
    classes = _phone_classes(corpus, masks)
    rates = [recorded_track(u).fps for u, mask in zip(corpus, masks) if mask.any()]
    jaw = dynamics = None
    if "jawOpen" in needed:
        jaw = [t.values[mask][:, needed.index("jawOpen")] for t, mask in zip(targets, masks) if mask.any()]
        dynamics = motion_profile(jaw, rates)
    return _Reference(needed, masks, targets, closed, shapes, classes, rates, jaw, dynamics)


def _phone_classes(corpus: Corpus, masks: list[np.ndarray], lags: list[int] | None = None) -> np.ndarray:
    """The phone class (:func:`frame_classes`) of every scored frame; with ``lags`` (frames per
    utterance, as ``sync`` moved the predictions) the phones moved alike, onto the picture's time."""
    classes = []
    for u, mask, lag in zip(corpus, masks, lags or [0] * len(masks)):
        track = recorded_track(u)
        labels = frame_classes(_phones(u), track.fps, len(mask), track.start_time)
        if lag:  # frame t shows what was heard at t + lag, as predict_on_frames moves the predictions
            labels = labels[np.clip(np.arange(len(labels)) + lag, 0, len(labels) - 1)]
        classes.append(labels[mask])
    return np.concatenate(classes)


def _evaluate_model(
    label: str,
    model: Estimator,
    chosen: tuple[str, ...],
    corpus: Corpus,
    reference: _Reference,
    how: tuple[str, bool],
    lags: list[int] | None,
    advance: Callable[[int], object],
) -> ModelEvaluation:
    """Score ``model`` on the ``chosen`` channels of every utterance, predicted ``how``
    (post-processing, transcript: :func:`predict_on_frames`) and moved by the utterance's lag
    (frames; ``None``: none), calling ``advance(1)`` after each."""
    columns = [reference.needed.index(c) for c in chosen]
    target_arrays, predicted_arrays = [], []
    closures: ClosureCounts | None = ClosureCounts()
    for k, (utterance, mask, target, tracked) in enumerate(
        zip(corpus, reference.masks, reference.targets, reference.closed)
    ):
        lag = 0 if lags is None else lags[k]
        predicted = predict_on_frames(model, utterance, *how, lag)
        target_arrays.append(target.values[mask][:, columns])
        predicted_arrays.append(predicted.select(chosen).values[mask])
        if closures is not None and tracked is not None and lip_opening(predicted) is not None:
            fps = recorded_track(utterance).fps
            closures += count_closures(  # the phones moved with the predictions: sound time onto the picture's
                _phones(utterance),
                fps,
                tracked,
                model_closed(predicted),
                mask,
                recorded_track(utterance).start_time + lag / fps,
            )
        else:
            closures = None
        advance(1)
    scores = score_channels(chosen, target_arrays, predicted_arrays)
    dynamics = by_phone = None
    if "jawOpen" in chosen:
        jaw = chosen.index("jawOpen")
        dynamics, by_phone = _jaw_measures(jaw, scores.range[jaw], target_arrays, predicted_arrays, reference)
    lips = None
    if reference.shapes is not None and any(len(t) for t in target_arrays):
        lips = lip_vertex_error(target_arrays, predicted_arrays, reference.shapes)
    return ModelEvaluation(label, model.name, scores, closures, dynamics, lips, by_phone)


def _jaw_measures(
    jaw: int, span: float, targets: list[np.ndarray], predictions: list[np.ndarray], reference: _Reference
) -> tuple[dict[str, float], dict[str, float]]:
    """The predicted jawOpen's (column ``jaw``) motion and lag against the recording's, and its
    RMSE in % of ``span`` by phone class."""
    predicted_jaw = [p[:, jaw] for p in predictions if len(p)]
    assert reference.jaw is not None  # set: "jawOpen" is among the channels needed
    dynamics = {
        **motion_profile(predicted_jaw, reference.rates),
        "lag_s": best_lag(reference.jaw, predicted_jaw, reference.rates),
    }
    errors = np.concatenate([p[:, jaw] - t[:, jaw] for t, p in zip(targets, predictions)])
    by_phone = {
        name: float(100 * np.sqrt(np.mean(errors[reference.classes == k] ** 2)) / span)
        if (reference.classes == k).any() and span > 0
        else float("nan")
        for k, name in enumerate(PHONE_CLASSES)
    }
    return dynamics, by_phone


def _landmarks(utterance: Utterance) -> dict[str, np.ndarray]:
    """The utterance's landmarks, where the caller has checked it has them."""
    assert utterance.landmarks is not None
    return utterance.landmarks


def _has_lip_landmarks(utterance: Utterance) -> bool:
    return utterance.landmarks is not None and all(f"lm{k}" in utterance.landmarks for k in (13, 14, 33, 263))
