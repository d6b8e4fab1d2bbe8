"""Models by name: create a default-configured one, load a shipped trained one or a saved folder.

A model module registers its class with :func:`vispeech.models.contract.register_model`; the
modules imported here are the ones the registry knows. A new model adds its import below.
Trained models shipped with the package live in ``vispeech/models/pretrained`` (see its
``MODEL_CARD.md``) and are listed in :data:`PRETRAINED`.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.models.networks import sliding_window, tdnn  # noqa: F401  (registration)
from vispeech.models.rules import baseline, beskow_rules, cohen_massaro, ohman  # noqa: F401  (registration)
from vispeech.models.contract import _MODELS, ControlModel

PRETRAINED: dict[str, str] = {
    "grid-tdnn": "grid_tdnn",
    "grid-tdnn-lowlatency": "grid_tdnn_lowlatency",
}
"""Shipped trained models: name → folder in ``vispeech/models/pretrained``."""

MODEL_NAMES: tuple[str, ...] = tuple(_MODELS) + tuple(PRETRAINED)
"""Names :func:`create_model` and :func:`load_model` accept."""


def model_class(name: str) -> type[ControlModel]:
    """The class registered under ``name``."""
    try:
        return _MODELS[name]
    except KeyError:
        raise VispeechError(f"unknown model {name!r} (use one of: {', '.join(_MODELS)})") from None


def pretrained_path(name: str) -> Path:
    """The saved-model folder of the shipped model ``name`` (one of :data:`PRETRAINED`)."""
    if name not in PRETRAINED:
        raise VispeechError(f"no shipped model {name!r} (there are: {', '.join(PRETRAINED)})")
    return Path(str(resources.files("vispeech.models") / "pretrained" / PRETRAINED[name]))


def create_model(name: str, **options) -> ControlModel:
    """A model ``name`` with its default parameters, replaced by ``options``; a
    :data:`PRETRAINED` name gives that trained model as shipped (it takes no options)."""
    if name in PRETRAINED:
        if options:
            raise VispeechError(f"the shipped model {name} takes no options; create its architecture "
                                f"({ControlModel.load(pretrained_path(name)).name}) to train one")
        return ControlModel.load(pretrained_path(name))
    return model_class(name)(**options)


def load_model(path_or_name: str | os.PathLike) -> ControlModel:
    """A registered or shipped model name gives that model (:func:`create_model`); anything
    else is a saved model folder."""
    if isinstance(path_or_name, str) and path_or_name in MODEL_NAMES:
        return create_model(path_or_name)
    if not os.path.isdir(path_or_name):
        raise VispeechError(
            f"unknown model {str(path_or_name)!r}: not one of {', '.join(MODEL_NAMES)} nor a saved model folder"
        )
    return ControlModel.load(path_or_name)
