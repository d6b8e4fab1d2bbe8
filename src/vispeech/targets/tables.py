"""Per-phone ARKit targets and per-phone parameter specs, read from ``data/targets.json``.

A phone's target is where the mouth and jaw aim during that phone, one value in [0, 1] per
channel of :data:`TARGET_CHANNELS`. It comes from the phone's articulatory feature vector
through an affine map (``bias + features · weights``, clipped to [0, 1]) and is then
corrected by authored per-phone overrides. Some channels are left *undefined* for some
phones (a /k/ does not care what the lips do): the Beskow rule model interpolates those from
the neighbours, the other models use the feature-derived value, and post-processing leaves
them alone. The data file's format is described in ``docs/models.md``.

Per-phone parameter *specs* (Cohen–Massaro's dominance, Öhman's coarticulation factors,
fade-out lengths) share one cascading format: ``{"default": value, "<feature or class>":
value, "<language>:<symbol>": value}``, where a value is a number or ``{channel: number}``.
Keys apply in order, later ones over earlier ones, phone keys last.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from functools import cache
from importlib import resources

import numpy as np

from vispeech.errors import VispeechError
from vispeech.phonetics.features import FEATURE_NAMES, PhoneRows, phone_rows
from vispeech.phonetics.inventory import LANGUAGES, get_inventory


@cache
def _data() -> dict:
    text = resources.files("vispeech.targets").joinpath("data/targets.json").read_text(encoding="utf-8")
    return json.loads(text)


TARGET_CHANNELS: tuple[str, ...] = tuple(_data()["channels"])
"""The ARKit channels every phone has a target for (and the data-free models predict)."""


def expand_channel(name: str, channels: Sequence[str] = TARGET_CHANNELS) -> tuple[str, ...]:
    """``name`` itself, or for a pair name such as ``mouthSmile`` its ``Left`` and ``Right`` channels."""
    if name in channels:
        return (name,)
    pair = (name + "Left", name + "Right")
    if all(c in channels for c in pair):
        return pair
    raise VispeechError(f"unknown target channel {name!r}")


def resolve_spec(spec: Mapping, language: str, channels: Sequence[str] | None = None) -> np.ndarray:
    """A per-phone parameter spec evaluated on every row of :func:`phone_rows`.

    Returns shape ``(rows,)`` when ``channels`` is ``None`` (values must be numbers), else
    ``(rows, len(channels))``. Keys cascade: ``default``, then class and feature keys in the
    spec's order, then ``<language>:<symbol>`` keys; a ``{channel: number}`` value sets only
    those channels (pair names such as ``mouthSmile`` set both sides).
    """
    if not isinstance(spec, Mapping) or "default" not in spec:
        raise VispeechError(f"a per-phone spec needs a 'default' entry, got {spec!r}")
    rows = phone_rows(language)
    shape = (len(rows.symbols),) if channels is None else (len(rows.symbols), len(channels))
    out = np.full(shape, np.nan)
    phone_keys = [k for k in spec if ":" in k]
    ordered = ["default"] + [k for k in spec if k != "default" and ":" not in k] + phone_keys
    for key in ordered:
        mask = rows.mask(key)
        value = spec[key]
        if isinstance(value, Mapping):
            if channels is None:
                raise VispeechError(f"spec entry {key!r} must be a number, got {value!r}")
            for name, number in value.items():
                for channel in expand_channel(name, channels):
                    out[mask, channels.index(channel)] = _number(number, key)
        else:
            out[mask] = _number(value, key)
    if np.isnan(out).any():
        raise VispeechError("the spec's 'default' entry must give every channel a value")
    return out


def _number(value, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise VispeechError(f"spec entry {key!r} must be a finite number, got {value!r}")
    return float(value)


class TargetTable:
    """Targets of every phone of every phone set: values and which of them are defined.

    ``overrides`` (``{"sv": {symbol: {channel: value or None}}, "en": {...}}``) apply on top
    of the data file's own overrides; ``None`` marks a channel undefined.
    """

    def __init__(self, overrides: Mapping | None = None):
        self.channels = TARGET_CHANNELS
        self._values: dict[str, np.ndarray] = {}
        self._defined: dict[str, np.ndarray] = {}
        self._bias, self._weights = self._feature_map(_data()["feature_map"])
        extra = overrides or {}
        if not isinstance(extra, Mapping) or not all(isinstance(t, Mapping) for t in extra.values()):
            raise VispeechError("target overrides must be {language: {symbol: {channel: value}}}")
        unknown = set(extra) - set(LANGUAGES)
        if unknown:
            raise VispeechError(f"target overrides for unknown language {min(unknown)!r}")
        self._extra = extra
        for language in extra:  # checked now; the other phone sets when first asked for
            self._build(language)

    def _build(self, language: str) -> None:
        """Compute the targets of ``language``'s rows (once)."""
        if language in self._values:
            return
        data = _data()
        rows = phone_rows(language)
        values = np.clip(self._bias + rows.features @ self._weights, 0.0, 1.0)
        defined = np.ones(values.shape, dtype=bool)
        for rule in data["underspecified"]:
            when = np.all([rows.features[:, FEATURE_NAMES.index(f)] == v for f, v in rule["when"].items()], axis=0)
            for state in ("defined", "undefined"):
                for channel in self._columns(rule.get(state, ())):
                    defined[when, channel] = state == "defined"
        for table in (data["overrides"].get(language, {}), self._extra.get(language, {})):
            self._apply_overrides(table, rows, values, defined)
        values.setflags(write=False)
        defined.setflags(write=False)
        self._values[language], self._defined[language] = values, defined

    def _columns(self, names: Iterable[str]) -> list[int]:
        return [self.channels.index(c) for name in names for c in expand_channel(name)]

    def _feature_map(self, spec: Mapping) -> tuple[np.ndarray, np.ndarray]:
        bias = np.zeros(len(self.channels))
        weights = np.zeros((len(FEATURE_NAMES), len(self.channels)))
        for name, value in spec["bias"].items():
            bias[self._columns([name])] = value
        for feature, row in spec["weights"].items():
            if feature not in FEATURE_NAMES:
                raise VispeechError(f"feature map names unknown feature {feature!r}")
            for name, value in row.items():
                weights[FEATURE_NAMES.index(feature), self._columns([name])] = value
        return bias, weights

    def _apply_overrides(self, table: Mapping, rows: PhoneRows, values: np.ndarray, defined: np.ndarray) -> None:
        for symbol, targets in table.items():
            if not isinstance(targets, Mapping):
                raise VispeechError(f"target override of {symbol!r} must be {{channel: value}}, got {targets!r}")
            selected = [rows.keys.get((symbol, False)), rows.keys.get((symbol, True))]
            if None in selected:
                raise VispeechError(f"target override for unknown phone {symbol!r} ({rows.language})")
            for name, value in targets.items():
                columns = self._columns([name])
                for row in selected:
                    if value is None:
                        defined[row, columns] = False
                    elif isinstance(value, (int, float)) and 0.0 <= value <= 1.0:
                        values[row, columns] = value
                        defined[row, columns] = True
                    else:
                        raise VispeechError(f"target of {symbol!r} for {name} must be in [0, 1] or null, got {value!r}")

    def values(self, language: str) -> np.ndarray:
        """Targets of every row of :func:`phone_rows` (undefined ones hold the feature-derived value)."""
        get_inventory(language)
        self._build(language)
        return self._values[language]

    def defined(self, language: str) -> np.ndarray:
        """Which entries of :meth:`values` the phone actually specifies."""
        get_inventory(language)
        self._build(language)
        return self._defined[language]


@cache
def default_targets() -> TargetTable:
    """The data file's targets, without further overrides."""
    return TargetTable()


def target_matrix(
    symbols: Sequence[str], language: str, stresses: Sequence[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(values, defined)``, each ``len(symbols) × len(TARGET_CHANNELS)``, for a phone list."""
    table = default_targets()
    rows = phone_rows(language).indices(symbols, stresses if stresses is not None else [0] * len(symbols))
    return table.values(language)[rows], table.defined(language)[rows]


def phone_targets(symbol: str, language: str, stress: int = 0) -> dict[str, float | None]:
    """``{channel: target}`` of one phone; ``None`` for channels it leaves undefined."""
    values, defined = target_matrix([symbol], language, [stress])
    return {c: (float(v) if d else None) for c, v, d in zip(TARGET_CHANNELS, values[0], defined[0])}
