"""The base of the rule families: models driven by per-phone target tables.

Their hyper-parameter defaults live in ``defaults.json`` beside this module; every family
also takes ``targets``, per-phone target overrides (``{"sv": {symbol: {channel: value}}}``)
applied over the data file's (:class:`vispeech.targets.tables.TargetTable`). Data-free
families predict from those authored tables; fitted ones (:meth:`fit`) keep what they learned
in ``tables_``: per language, arrays over the rows of :func:`~vispeech.targets.tables.phone_rows`.
"""

from __future__ import annotations

import json
from functools import cache, cached_property
from importlib import resources
from typing import ClassVar

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.contract import Estimator
from vispeech.models.fitting import FitRun
from vispeech.models.history import TrainingHistory
from vispeech.models.rules.segments import Segments
from vispeech.motion.track import Track
from vispeech.targets.tables import TARGET_CHANNELS, TargetTable


@cache
def family_defaults(family: str) -> dict:
    """The hyper-parameter defaults of a rule family, from ``defaults.json``."""
    text = resources.files("vispeech.models.rules").joinpath("defaults.json").read_text(encoding="utf-8")
    return {**json.loads(text)[family], "targets": {}}


class PhoneTargetModel(Estimator[PhoneSequence]):
    """A rule family: per-phone targets (and, in subclasses, per-phone timing parameters)."""

    data_free = True
    trainable = False
    table_names: ClassVar[tuple[str, ...]] = ("targets",)
    """The per-row arrays of one language that :meth:`fit` learns (``tables_[language][name]``)."""

    def _check_params(self) -> None:
        self._authored_cache: dict[str, dict[str, np.ndarray]] = {}
        self.__dict__.pop("_authored_table", None)
        self._authored_table  # noqa: B018  (validates the target overrides)

    @property
    def channels(self) -> tuple[str, ...]:
        return TARGET_CHANNELS

    @cached_property
    def _authored_table(self) -> TargetTable:
        return TargetTable(self._params["targets"])

    def _authored(self, language: str) -> dict[str, np.ndarray]:
        """The tables of ``language`` given by the hyper-parameters (computed once)."""
        if language not in self._authored_cache:
            self._authored_cache[language] = self._authored_tables(language)
        return self._authored_cache[language]

    def _authored_tables(self, language: str) -> dict[str, np.ndarray]:
        """Per-row arrays of ``language`` from the hyper-parameters; subclasses add theirs to the targets."""
        return {"targets": self._authored_table.values(language)}

    def tables(self, language: str) -> dict[str, np.ndarray]:
        """The per-row arrays the model predicts ``language`` with: learned if fitted, else authored."""
        learned = getattr(self, "tables_", None)
        if learned is not None and language in learned:
            return learned[language]
        return self._authored(language)

    def segments(self, phones: PhoneSequence, fps: float) -> Segments:
        """The gap-filled segments of ``phones`` with their targets, and the frame times (both checked:
        :meth:`~vispeech.models.contract.Estimator.check_inputs`)."""
        self.check_inputs(phones, fps)
        table = self._authored_table
        segments = Segments.build(phones, fps, table.values(phones.language), table.defined(phones.language))
        learned = self.tables(phones.language)["targets"]
        return segments if learned is table.values(phones.language) else segments.with_targets(learned)

    def _check_fit_params(self) -> None:
        """Raise :class:`VispeechError` on bad ``channels``, ``max_iterations`` or ``patience``."""
        p = self._params
        if p["channels"] is not None:
            unknown = [
                c
                for c in ([p["channels"]] if isinstance(p["channels"], str) else p["channels"])
                if c not in self.channels
            ]
            if unknown or not p["channels"]:
                raise VispeechError(f"model {self.family} does not predict channels {', '.join(unknown) or '(none)'}")
        for key, least in (("max_iterations", 0), ("patience", 1)):
            value = p[key]
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise VispeechError(f"{key} must be a whole number >= {least}, got {value!r}")

    def _track(self, values: np.ndarray, fps: float) -> Track:
        return Track(np.clip(values, 0.0, 1.0), self.channels, fps)

    def _fit(self, corpus, run: FitRun) -> PhoneTargetModel:
        raise VispeechError(f"model {self.family} is data-free: its parameters are authored, not fitted")

    def _learned_state(self):
        learned = getattr(self, "tables_", None)
        if learned is None:
            return None
        arrays = {
            f"{language}.{name}": values for language, tables in learned.items() for name, values in tables.items()
        }
        return {"channels": list(self.fitted_channels_), "history": self.history_.to_dict()}, arrays

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        learned: dict[str, dict[str, np.ndarray]] = {}
        for key, values in arrays.items():
            language, _, name = key.partition(".")
            if name not in self.table_names:
                raise ValueError(f"unknown table {key}")
            expected = self._authored(language)[name].shape
            if values.shape != expected:
                raise ValueError(f"table {key} has shape {values.shape}, expected {expected}")
            learned.setdefault(language, {})[name] = values.astype(np.float64)
        incomplete = [language for language, tables in learned.items() if set(tables) != set(self.table_names)]
        if not learned or incomplete:
            raise ValueError(f"learned tables must give {', '.join(self.table_names)} for each language")
        self.tables_ = learned
        self.fitted_channels_ = tuple(state["channels"])
        self.history_ = TrainingHistory.from_dict(state["history"])
