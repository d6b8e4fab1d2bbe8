"""Models by name: the families, the shipped trained models, and saved folders.

One name per model: :func:`load_model` takes a shipped model's name (``grid-tdnn``), a
data-free family's name (``baseline``: its authored parameters) or a saved model folder, and
the model it gives reports that name as :attr:`~vispeech.models.contract.Estimator.name`.
Families that need training are created with :func:`create_model` and fitted (``vispeech
train``). Family classes are imported when first asked for, so naming a model costs nothing.
Shipped models live in ``vispeech/models/pretrained`` (see its ``MODEL_CARD.md``).
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.models.contract import Estimator
from vispeech.models.persistence import model_from_config, read_config

FAMILIES: dict[str, str] = {
    "audio-cnn": "vispeech.models.networks.audio:AudioCNNNetwork",
    "audio-encdec": "vispeech.models.networks.audio:EncoderDecoderNetwork",
    "audio-ensemble": "vispeech.models.ensemble:AudioEnsemble",
    "baseline": "vispeech.models.rules.baseline:Baseline",
    "beskow-rules": "vispeech.models.rules.beskow_rules:BeskowRules",
    "cohen-massaro": "vispeech.models.rules.cohen_massaro:CohenMassaro",
    "ohman": "vispeech.models.rules.ohman:Ohman",
    "sliding-window-thesis": "vispeech.models.networks.sliding_window:SlidingWindowNetwork",
    "sliding-window-taylor": "vispeech.models.networks.sliding_window:TaylorNetwork",
    "lstm-taylor": "vispeech.models.networks.lstm:LSTMNetwork",
    "sliding-window-dtree": "vispeech.models.networks.decision_tree:DecisionTreeRegression",
    "tdnn-beskow": "vispeech.models.networks.tdnn:TimeDelayNetwork",
    "tdnn-lowlatency": "vispeech.models.networks.tdnn:LowLatencyNetwork",
}
"""Every family: name → ``module:class``."""

DATA_FREE: tuple[str, ...] = ("baseline", "beskow-rules", "cohen-massaro", "ohman")
"""Families that run on their authored parameters without training."""

PRETRAINED: dict[str, str] = {
    "grid-tdnn": "grid_tdnn",
    "grid-tdnn-lowlatency": "grid_tdnn_lowlatency",
    "grid-cohen-massaro": "grid_cohen_massaro",
    "grid-ohman": "grid_ohman",
    "grid-audio-cnn": "grid_audio_cnn",
    "grid-audio-encdec": "grid_audio_encdec",
    "grid-audio-whisper": "grid_audio_whisper",
    "grid-audio-whisper-base": "grid_audio_whisper_base",
    "grid-audio-whisper-ensemble": "grid_audio_whisper_ensemble",
}
"""Shipped trained models: name → folder in ``vispeech/models/pretrained``."""

RUNNABLE: tuple[str, ...] = (*PRETRAINED, *DATA_FREE)
"""Names :func:`load_model` takes: what ``--model`` offers."""


def family_class(family: str) -> type[Estimator]:
    """The class of a family (imported on first use)."""
    try:
        module, _, name = FAMILIES[family].partition(":")
    except KeyError:
        raise VispeechError(f"unknown model family {family!r} (use one of: {', '.join(FAMILIES)})") from None
    return getattr(importlib.import_module(module), name)


def create_model(family: str, **params) -> Estimator:
    """A new model of ``family`` with ``params`` over its default hyper-parameters."""
    return family_class(family)(**params)


def pretrained_path(name: str) -> Path:
    """The saved-model folder of the shipped model ``name`` (one of :data:`PRETRAINED`)."""
    if name not in PRETRAINED:
        raise VispeechError(f"no shipped model {name!r} (there are: {', '.join(PRETRAINED)})")
    return Path(str(resources.files("vispeech.models") / "pretrained" / PRETRAINED[name]))


def load_model(name_or_path: str | os.PathLike) -> Estimator:
    """The model a name of :data:`RUNNABLE` or a saved folder gives, known by that name.

    Raises :class:`VispeechError` for anything else (naming the families to train instead).
    """
    if isinstance(name_or_path, str) and name_or_path in PRETRAINED:
        return load_folder(pretrained_path(name_or_path))
    if isinstance(name_or_path, str) and name_or_path in DATA_FREE:
        return create_model(name_or_path)
    if isinstance(name_or_path, str) and name_or_path in FAMILIES and not family_class(name_or_path).trainable:
        raise VispeechError(
            f"model family {name_or_path} learns nothing itself: give its parameters (members) in Python "
            f"and load the folder it saves; ready to run: {', '.join(RUNNABLE)}"
        )
    if isinstance(name_or_path, str) and name_or_path in FAMILIES:
        raise VispeechError(
            f"model {name_or_path} must be trained first (vispeech train --model {name_or_path}); "
            f"ready to run: {', '.join(RUNNABLE)}"
        )
    if not os.path.isdir(name_or_path):
        if not isinstance(name_or_path, str):  # a path names a folder; a shipped model is named by a string
            raise VispeechError(f"no saved model folder at {os.fspath(name_or_path)}")
        known = ", ".join(RUNNABLE)
        raise VispeechError(f"unknown model {name_or_path!r}: not one of {known} nor a saved model folder")
    return load_folder(name_or_path)


def saved_folder(name_or_path: str | os.PathLike) -> Path | None:
    """The folder a model name or path is saved in (a shipped model's, or the path itself);
    ``None`` for a data-free family."""
    if isinstance(name_or_path, str) and name_or_path in PRETRAINED:
        return pretrained_path(name_or_path)
    if isinstance(name_or_path, str) and name_or_path in DATA_FREE:
        return None
    return Path(name_or_path) if os.path.isdir(name_or_path) else None


def model_version(model: Estimator, folder: Path | None = None) -> str:
    """16 hex digits that change whenever ``model``'s output may: vispeech's version, the model's
    name and parameters, the files of the ``folder`` it was loaded from (its weights) and the
    versions of the saved models it animates with (:meth:`~vispeech.models.contract.Estimator.saved_parts`)."""
    import hashlib
    import json

    import vispeech

    about = {"vispeech": vispeech.__version__, "model": model.name, "params": model.get_params()}
    digest = hashlib.sha256(json.dumps(about, sort_keys=True, default=str).encode())
    if folder is not None:
        for path in sorted(folder.iterdir()):
            if path.is_file():
                digest.update(path.name.encode() + path.read_bytes())
    for part, part_folder in model.saved_parts():
        digest.update(model_version(part, part_folder).encode())
    return digest.hexdigest()[:16]


def load_folder(folder: str | os.PathLike) -> Estimator:
    """The model saved in ``folder``, whatever its family."""
    folder = Path(folder)
    config = read_config(folder)
    return model_from_config(family_class(config["family"]), folder, config)


@dataclass(frozen=True)
class ModelInfo:
    """One line of ``vispeech models``: what a runnable model is and how well it does."""

    name: str
    family: str
    input: str
    lookahead: int
    fps: float | None
    trained_on: str
    score: str


def describe_models() -> list[ModelInfo]:
    """Every runnable model with its family, input, look-ahead, training data and test-split figure."""
    import json

    authored = json.loads(resources.files("vispeech.models.rules").joinpath("cards.json").read_text(encoding="utf-8"))
    infos = []
    for name in RUNNABLE:
        model = load_model(name)
        if name in PRETRAINED:
            card = json.loads((pretrained_path(name) / "card.json").read_text(encoding="utf-8"))
            trained_on, score = card["trained_on"], card["test"]
        else:
            trained_on, score = "authored (data-free)", authored[name]
        infos.append(
            ModelInfo(name, model.family, model.input_kind, model.lookahead, model.frame_rate, trained_on, score)
        )
    return infos
