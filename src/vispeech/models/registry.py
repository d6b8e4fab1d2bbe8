"""Models by name: create a default-configured one or load a saved folder.

A model module registers its class with :func:`vispeech.models.base.register_model`; the
modules imported here are the ones the registry knows. A new model adds its import below.
"""

from __future__ import annotations

import os

from vispeech.errors import VispeechError
from vispeech.models import (  # noqa: F401  (registration)
    baseline, beskow_rules, cohen_massaro, ohman, sliding_window, tdnn,
)
from vispeech.models.base import _MODELS, ControlModel

MODEL_NAMES: tuple[str, ...] = tuple(_MODELS)
"""Names :func:`create_model` and :func:`load_model` accept."""


def model_class(name: str) -> type[ControlModel]:
    """The class registered under ``name``."""
    try:
        return _MODELS[name]
    except KeyError:
        raise VispeechError(f"unknown model {name!r} (use one of: {', '.join(_MODELS)})") from None


def create_model(name: str, **options) -> ControlModel:
    """A model ``name`` with its default parameters, replaced by ``options``."""
    return model_class(name)(**options)


def load_model(path_or_name: str | os.PathLike) -> ControlModel:
    """A registered model name gives that model with defaults; anything else is a saved model folder."""
    if isinstance(path_or_name, str) and path_or_name in _MODELS:
        return create_model(path_or_name)
    if not os.path.isdir(path_or_name):
        raise VispeechError(
            f"unknown model {str(path_or_name)!r}: not one of {', '.join(_MODELS)} nor a saved model folder"
        )
    return ControlModel.load(path_or_name)
