"""Objective evaluation of control models against recorded face tracks.

:func:`evaluate_models` scores models on a corpus split (MSE, RMSE as % of range, Pearson r
over the speech span) and counts lip closures; see ``docs/evaluation.md``.
"""

from vispeech.evaluation.closures import (
    ClosureCounts,
    count_closures,
    lip_opening,
    model_closed,
    tracked_closed,
)
from vispeech.evaluation.metrics import (
    ChannelScores,
    mse,
    pearson_r,
    rmse_percent,
    score_channels,
    speech_frames,
    value_range,
)
from vispeech.evaluation.report import (
    Evaluation,
    ModelEvaluation,
    evaluate_models,
    model_channels,
    predict_on_frames,
    scored_frames,
    target_track,
)

__all__ = [
    "ChannelScores",
    "ClosureCounts",
    "Evaluation",
    "ModelEvaluation",
    "count_closures",
    "evaluate_models",
    "lip_opening",
    "model_channels",
    "model_closed",
    "mse",
    "pearson_r",
    "predict_on_frames",
    "rmse_percent",
    "score_channels",
    "scored_frames",
    "speech_frames",
    "target_track",
    "tracked_closed",
    "value_range",
]
