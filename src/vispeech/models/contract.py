"""The control-model protocol: ``predict`` phones to a track, ``fit``, ``save`` and ``load``.

Every model saves to the same folder format: ``config.json`` holding
``{"model", "version", "vispeech", "channels", "params", "arrays"}`` (plus
``"postprocessing"`` when the model recommends its own post-processing) and, only when the
model has arrays (``"arrays"`` lists their names), ``weights.npz`` (read without pickle).
"""

from __future__ import annotations

import copy
import json
import os
import zipfile
from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.models.rules.segments import Segments
from vispeech.targets.tables import TargetTable, default_model_params
from vispeech.motion.track import Track

FORMAT_VERSION = 1
"""Version of the saved-model folder format; loading refuses newer ones."""

_MODELS: dict[str, type[ControlModel]] = {}


def register_model(cls: type[ControlModel]) -> type[ControlModel]:
    """Class decorator: make a model known by its ``name`` to the registry and to :meth:`ControlModel.load`."""
    if not cls.name or cls.name in _MODELS:
        raise VispeechError(f"cannot register model {cls.name!r}: empty or taken name")
    _MODELS[cls.name] = cls
    return cls


class ControlModel(ABC):
    """Turns a time-aligned phone sequence into an animation track.

    Parameters come from :meth:`default_params`, replaced key by key by ``params`` and then
    by keyword ``options``; :meth:`get_params` gives them back as a plain JSON-ready dict.
    """

    name: ClassVar[str] = ""
    channels: tuple[str, ...] = ()
    postprocessing: dict | None = None
    """Recommended post-processing: :class:`vispeech.postprocess.PostprocessConfig` fields as
    plain JSON, used by :func:`vispeech.pipeline.animate` instead of the defaults; saved in
    ``config.json`` as ``"postprocessing"`` (left out when ``None``)."""

    def __init__(self, params: Mapping | None = None, **options):
        merged = self.default_params()
        for source in (params or {}, options):
            for key, value in source.items():
                if key not in merged:
                    known = ", ".join(sorted(merged))
                    raise VispeechError(f"model {self.name} has no parameter {key!r} (it has: {known})")
                merged[key] = copy.deepcopy(value)
        self._params = merged

    @classmethod
    def default_params(cls) -> dict:
        """The parameters a model has when none are given."""
        return {}

    @abstractmethod
    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        """A track of ``phones.n_frames(fps)`` frames from time 0 over :attr:`channels`."""

    def fit(self, corpus) -> ControlModel:
        """Estimate the parameters from a corpus; returns ``self``."""
        raise VispeechError(f"model {self.name} is not trainable")

    def get_params(self) -> dict:
        """A copy of the parameters as a plain dict."""
        return copy.deepcopy(self._params)

    @property
    def params(self) -> dict:
        return self.get_params()

    def _arrays(self) -> dict[str, np.ndarray]:
        """Arrays saved beside the parameters in ``weights.npz`` (none by default)."""
        return {}

    @classmethod
    def _from_saved(cls, params: dict, arrays: dict[str, np.ndarray]) -> ControlModel:
        """Rebuild a saved model; models with arrays override this."""
        if arrays:
            raise VispeechError(f"model {cls.name} has no arrays but the saved folder has {sorted(arrays)}")
        return cls(params)

    @classmethod
    def _from_folder(cls, folder: Path, config: dict) -> ControlModel:
        """Rebuild a saved model from its folder and parsed ``config.json``.

        Reads ``weights.npz`` and calls :meth:`_from_saved`; models that keep their weights
        in another file (the torch networks: ``weights.safetensors``) override this.
        """
        names = list(config.get("arrays", []))
        arrays = _read_arrays(folder / "weights.npz", names) if names else {}
        return cls._from_saved(config["params"], arrays)

    def _config(self, arrays: list[str]) -> dict:
        """The ``config.json`` every saved model starts from (``arrays``: names in its weights)."""
        config = {
            "model": self.name,
            "version": FORMAT_VERSION,
            "vispeech": _package_version(),
            "channels": list(self.channels),
            "params": self.get_params(),
            "arrays": arrays,
        }
        if self.postprocessing is not None:
            config["postprocessing"] = self.postprocessing
        return config

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model into folder ``path`` (created if needed) atomically; returns the folder."""
        arrays = self._arrays()
        config = self._config(sorted(arrays))
        with atomic_output_dir(path) as staging:
            (staging / "config.json").write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
            if arrays:
                with open(staging / "weights.npz", "wb") as handle:
                    np.savez(handle, **arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> ControlModel:
        """Read a folder written by :meth:`save`; raises :class:`VispeechError` if it is missing or corrupt."""
        import vispeech.models.registry  # noqa: F401  (registers the built-in models)

        folder = Path(path)
        config_path = folder / "config.json"
        if not config_path.is_file():
            raise VispeechError(f"no saved model at {folder} (config.json missing)")
        try:
            config = json.loads(config_path.read_text(encoding="utf-8"))
            name, version, params = config["model"], config["version"], config["params"]
            channels = list(config["channels"])
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
            raise VispeechError(f"corrupt model config {config_path}: {exc}") from None
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise VispeechError(f"{config_path} has format version {version!r}; this vispeech reads up to {FORMAT_VERSION}")
        if name not in _MODELS:
            raise VispeechError(f"{config_path} names unknown model {name!r}")
        model_cls = _MODELS[name]
        if not issubclass(model_cls, cls):
            raise VispeechError(f"{folder} holds a {name} model, not a {cls.name} model")
        if not isinstance(params, dict) or not isinstance(config.get("arrays", []), list):
            raise VispeechError(f"corrupt model config {config_path}: params must be an object and arrays a list")
        recommended = config.get("postprocessing")
        if recommended is not None and not isinstance(recommended, dict):
            raise VispeechError(f"corrupt model config {config_path}: postprocessing must be an object")
        model = model_cls._from_folder(folder, config)
        if list(model.channels) != channels:
            raise VispeechError(f"{config_path} lists channels that do not match the {name} model's")
        model.postprocessing = recommended
        return model


def _read_arrays(path: Path, names: list[str]) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise VispeechError(f"cannot read model weights {path}: {exc}") from None
    if sorted(arrays) != sorted(names):
        raise VispeechError(f"{path} holds arrays {sorted(arrays)}, the config lists {sorted(names)}")
    return arrays


def _package_version() -> str:
    from vispeech import __version__

    return __version__


class PhoneTargetModel(ControlModel):
    """A data-free model driven by the per-phone target table.

    Defaults come from the ``models`` section of ``data/targets.json``; the extra parameter
    ``targets`` holds per-phone target overrides (``{"sv": {symbol: {channel: value}}}``)
    applied on top of the data file's, so estimated targets can be plugged in.
    """

    def __init__(self, params: Mapping | None = None, **options):
        super().__init__(params, **options)
        self.table = TargetTable(self._params["targets"])
        self.channels = self.table.channels

    @classmethod
    def default_params(cls) -> dict:
        return {**default_model_params(cls.name), "targets": {}}

    def segments(self, phones: PhoneSequence, fps: float) -> Segments:
        """The gap-filled segments of ``phones`` with their targets, and the frame times."""
        return Segments.build(phones, fps, self.table)

    def _track(self, values: np.ndarray, fps: float) -> Track:
        return Track(np.clip(values, 0.0, 1.0), self.channels, fps)
