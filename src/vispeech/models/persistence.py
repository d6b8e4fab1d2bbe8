"""Saved models: a folder with ``config.json`` and, when there are arrays, ``weights.safetensors``.

``config.json`` holds ``format`` (:data:`FORMAT`), ``version`` (:data:`FORMAT_VERSION`),
``name``, ``family``, ``input``, the vispeech version that wrote it, ``channels``, ``params``
(the hyper-parameters), the learned ``state`` as JSON, the names of the learned ``arrays`` and
the recommended ``postprocessing`` preset. No pickle. :meth:`Estimator.save
<vispeech.models.contract.Estimator.save>` and :meth:`~vispeech.models.contract.Estimator.load`
are written with :func:`write_model` and :func:`model_from_config`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from vispeech.errors import VispeechError

if TYPE_CHECKING:
    from vispeech.models.contract import Estimator

    _Model = TypeVar("_Model", bound=Estimator)

FORMAT = "vispeech-model"
FORMAT_VERSION = 2
"""Version of the saved-model folder format; loading refuses others."""
CONFIG = "config.json"
WEIGHTS = "weights.safetensors"
FOLDER_NAMES = (CONFIG, WEIGHTS, "training_state.json", "training_state.safetensors", "loss_curve.png", "checkpoint")
"""What a model folder may hold (beside the model: a network's training state, and ``vispeech
train``'s loss curve and checkpoint sub-folder); :meth:`Estimator.save` replaces a folder
holding only these."""
INPUT_KINDS = ("phones", "audio")
RETIRED_PARAMS = frozenset({"checkpoint_dir", "num_threads", "warm_start"})
"""Run settings that were hyper-parameters of the networks before they became keywords of
:meth:`~vispeech.models.contract.Estimator.fit`: a folder saved then may still list them."""


def write_model(model: Estimator, folder: Path, name: str) -> None:
    """Write ``config.json`` (and ``weights.safetensors``) of ``model``, known by ``name``, into
    ``folder``, which exists: the staging folder of a save or of a checkpoint that adds files of
    its own."""
    from safetensors.numpy import save as to_safetensors

    learned = model._learned_state()
    state, arrays = learned if learned is not None else (None, {})
    config = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "name": name,
        "family": model.family,
        "input": model.input_kind,
        "vispeech": _package_version(),
        "channels": list(model.channels) if model.is_fitted else None,
        "params": model.get_params(),
        "state": state,
        "arrays": sorted(arrays),
        "postprocessing": model.postprocessing,
    }
    (folder / CONFIG).write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
    if arrays:
        tensors = {key: np.ascontiguousarray(value) for key, value in arrays.items()}
        (folder / WEIGHTS).write_bytes(to_safetensors(tensors))


def read_config(folder: Path) -> dict:
    """The checked ``config.json`` of a saved-model folder."""
    path = folder / CONFIG
    if not path.is_file():
        raise VispeechError(f"no saved model at {folder} ({CONFIG} missing)")
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
        if config.get("format") != FORMAT:
            raise ValueError(f"not a {FORMAT} folder")
        if config.get("version") != FORMAT_VERSION:
            raise ValueError(f"format version {config.get('version')!r}; this vispeech reads {FORMAT_VERSION}")
        for key, kind in (("name", str), ("family", str), ("params", dict), ("arrays", list), ("postprocessing", str)):
            if not isinstance(config.get(key), kind):
                raise ValueError(f"{key} must be a {kind.__name__}")
        if config.get("input") not in INPUT_KINDS or not isinstance(config.get("state"), dict | None):
            raise ValueError("input must be phones or audio and state an object or null")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError) as exc:
        raise VispeechError(f"corrupt model config {path}: {exc}") from None
    return config


def model_from_config(cls: type[_Model], folder: Path, config: dict) -> _Model:
    """The model of family class ``cls`` that ``folder`` holds, ``config`` being its checked
    ``config.json`` (:func:`read_config`); raises :class:`VispeechError` where they disagree."""
    # A folder saved before the run settings left the hyper-parameters may list them: dropped.
    params = {key: value for key, value in config["params"].items() if key not in RETIRED_PARAMS}
    if params.get("fps") == 0:  # saved before 2026-12-06, when fps 0 trained at the corpus's rate as null does
        params["fps"] = None
    try:
        model = cls(**params)
    except TypeError as exc:
        raise VispeechError(f"corrupt model config in {folder}: {exc}") from None
    model._name = config["name"]  # known by the name it was saved under
    if config["input"] != model.input_kind:
        raise VispeechError(
            f"{folder / CONFIG} says input {config['input']}, but {model.family} takes {model.input_kind}"
        )
    if config["state"] is None and config["arrays"]:
        raise VispeechError(f"{folder / CONFIG} lists learned arrays but no learned state")
    if config["state"] is not None:
        arrays = _read_arrays(folder / WEIGHTS, config["arrays"])
        try:
            model._set_learned_state(config["state"], arrays)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise VispeechError(f"corrupt model state in {folder}: {exc}") from None
    if config["channels"] is not None and list(model.channels) != config["channels"]:
        raise VispeechError(f"{folder / CONFIG} lists channels that do not match the {model.family} model's")
    if config["postprocessing"] != model.postprocessing:
        raise VispeechError(
            f"{folder / CONFIG} recommends post-processing {config['postprocessing']!r}, "
            f"but a {'fitted' if model.is_fitted else 'new'} {model.family} model recommends "
            f"{model.postprocessing!r}"
        )
    return model


def _read_arrays(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    if not names:
        return {}
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    try:
        arrays = load_file(path)
    except (OSError, SafetensorError, ValueError) as exc:
        raise VispeechError(f"cannot read model weights {path}: {exc}") from None
    if sorted(arrays) != sorted(names):
        raise VispeechError(f"{path} holds arrays {sorted(arrays)[:4]}..., its config lists others")
    return arrays


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vispeech")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"
