"""Retargeting: linear maps from ARKit channels to another rig's controls (pose tables).

A pose table is a readable JSON file of one of three kinds (see docs/formats.md):

- morph controls, each a linear combination of track channels::

      {"type": "morph", "controls": {"viseme_PP": {"mouthClose": 0.8, "mouthPressLeft": 0.4}},
       "bias": {"viseme_sil": 1.0}, "range": [0, 1]}

- morph controls given by the ARKit pose each stands for (e.g. TalkingHead's recipe
  ``viseme_aa = jawOpen 0.6``); the map is the ridge least-squares decomposition of a frame
  into those poses, and an optional ``rest`` control gets ``1 - sum(others)``::

      {"type": "morph", "poses": {"viseme_aa": {"jawOpen": 0.6}, ...}, "rest": "viseme_sil",
       "ridge": 0.02, "range": [0, 1]}

- bone transforms, each bone channel a linear combination (output channel ``bone.channel``)::

      {"type": "bones", "bones": {"jaw": {"rotation_x": {"jawOpen": 0.35}}}}

``bias`` (same nesting as the map) adds constants; ``range`` clips every output.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import read_text
from vispeech.limits import MAX_CHANNELS, MAX_POSE_TABLE_BYTES, parse_json
from vispeech.motion.track import Track

BUILTIN_TABLES: tuple[str, ...] = ("oculus_visemes", "rhubarb_shapes", "thesis_bone_rig")
"""Pose tables shipped in ``vispeech/motion/rigging/data`` (load them by name)."""


@dataclass(frozen=True)
class PoseTable:
    """``controls = clip(weights @ track[inputs] + bias, *range)``, frame by frame.

    Attributes
    ----------
    kind : ``"morph"`` or ``"bones"``.
    controls : output channel names (``bone.channel`` for bone tables).
    inputs : track channels read (missing ones count as 0).
    weights : array (n_controls, n_inputs).
    bias : array (n_controls,).
    clip : ``(low, high)`` applied to every output, or ``None``.
    name : a label for messages.
    """

    kind: str
    controls: tuple[str, ...]
    inputs: tuple[str, ...]
    weights: np.ndarray
    bias: np.ndarray
    clip: tuple[float, float] | None = None
    name: str = ""

    @classmethod
    def load(cls, source: str | os.PathLike) -> PoseTable:
        """Load a pose table from a JSON file, or a built-in one by name (:data:`BUILTIN_TABLES`)."""
        path = Path(source)
        if not os.path.lexists(path) and str(source) in BUILTIN_TABLES:
            path = Path(str(resources.files("vispeech.motion.rigging") / "data" / f"{source}.json"))
        if not os.path.lexists(path):
            raise VispeechError(f"pose table not found: {source} (built-in tables: {', '.join(BUILTIN_TABLES)})")
        data = parse_json(read_text(path, "pose table", MAX_POSE_TABLE_BYTES), f"pose table {path}")
        try:
            return cls.from_dict(data, name=path.stem)
        except VispeechError as exc:
            raise VispeechError(f"pose table {path}: {exc}") from None

    @classmethod
    def from_dict(cls, data: object, name: str = "") -> PoseTable:
        """Build a table from the JSON structure described in the module docstring."""
        if not isinstance(data, dict):
            raise VispeechError("a pose table must be a JSON object")
        kind = data.get("type")
        name = str(data.get("name", name))
        clip = _range(data.get("range"))
        if kind == "bones":
            bones = _mapping(data.get("bones"), "bones")
            dotted = [bone for bone in bones if "." in bone]
            if dotted:
                raise VispeechError(f"bone name {dotted[0]!r} must not contain '.'")
            rows = {
                f"{bone}.{channel}": combo
                for bone, channels in bones.items()
                for channel, combo in _mapping(channels, f"bones.{bone}").items()
            }
            bias = {
                f"{bone}.{channel}": value
                for bone, channels in _mapping(data.get("bias", {}), "bias").items()
                for channel, value in _mapping(channels, f"bias.{bone}").items()
            }
            return cls._linear(kind, rows, bias, clip, name)
        if kind != "morph":
            raise VispeechError(f"pose table type must be 'morph' or 'bones', got {kind!r}")
        if ("controls" in data) == ("poses" in data):
            raise VispeechError("a morph pose table needs exactly one of 'controls' and 'poses'")
        if "controls" in data:
            rows, bias = _mapping(data["controls"], "controls"), _mapping(data.get("bias", {}), "bias")
            return cls._linear(kind, rows, bias, clip, name)
        return cls.from_poses(
            _mapping(data["poses"], "poses"),
            rest=data.get("rest"),
            ridge=_number(data.get("ridge", 0.02), "ridge"),
            clip=clip,
            name=name,
        )

    @classmethod
    def from_poses(
        cls,
        poses: dict[str, dict[str, float]],
        rest: str | None = None,
        ridge: float = 0.02,
        clip: tuple[float, float] | None = (0.0, 1.0),
        name: str = "",
    ) -> PoseTable:
        """A morph table that decomposes each frame into the given poses.

        ``poses[control]`` is the ARKit pose that control stands for (rows of ``P``). The
        weights solve ``min_v |x - P.T v|^2 + r |v|^2`` for each frame ``x``, i.e.
        ``W = (P P.T + r I)^-1 P`` with ``r = ridge * mean(|p|^2)`` (so ``ridge`` does not
        depend on the poses' scale): a frame equal to one pose gives that control about 1 and
        the others about 0. ``rest`` (if given) is an extra control ``1 - sum(v)``.
        """
        if not poses:
            raise VispeechError("a pose table needs at least one pose")
        if ridge < 0:
            raise VispeechError(f"ridge must be non-negative, got {ridge}")
        controls = tuple(poses)
        inputs = tuple(sorted({ch for pose in poses.values() for ch in _mapping(pose, "poses")}))
        _check_size(len(controls), len(inputs))
        basis = np.array([[_number(poses[c].get(i, 0.0), f"poses.{c}.{i}") for i in inputs] for c in controls])
        with np.errstate(over="ignore", invalid="ignore"):
            gram = basis @ basis.T
        with np.errstate(over="ignore", invalid="ignore"):
            gram += ridge * np.mean(np.diag(gram)) * np.eye(len(controls))
        if not np.all(np.isfinite(gram)):
            raise VispeechError("the poses' values or the ridge are too large")
        try:
            if np.linalg.matrix_rank(gram) < len(controls):
                raise VispeechError("the poses are linearly dependent; give a positive ridge")
            weights = np.linalg.solve(gram, basis)
        except np.linalg.LinAlgError as exc:
            raise VispeechError(f"the poses cannot be decomposed ({exc})") from None
        bias = np.zeros(len(controls))
        if rest is not None:
            if rest in controls:
                raise VispeechError(f"rest control {rest!r} must not also be a pose")
            controls += (str(rest),)
            weights = np.vstack([weights, -weights.sum(axis=0)])
            bias = np.append(bias, 1.0)
        return cls("morph", controls, inputs, weights, bias, clip, name)

    @classmethod
    def _linear(cls, kind: str, rows: dict, bias: dict, clip, name: str) -> PoseTable:
        if not rows:
            raise VispeechError("a pose table needs at least one control")
        unknown = sorted(set(bias) - set(rows))
        if unknown:
            raise VispeechError(f"bias for unknown control {unknown[0]!r}")
        controls = tuple(rows)
        inputs = tuple(sorted({ch for combo in rows.values() for ch in _mapping(combo, "controls")}))
        _check_size(len(controls), len(inputs))
        weights = np.array([[_number(rows[c].get(i, 0.0), f"{c}.{i}") for i in inputs] for c in controls])
        offsets = np.array([_number(bias.get(c, 0.0), f"bias.{c}") for c in controls])
        return cls(kind, controls, inputs, weights.reshape(len(controls), len(inputs)), offsets, clip, name)

    def apply(self, track: Track) -> Track:
        """The track of this table's controls, same frames, fps and start time."""
        if self.inputs and not set(self.inputs) & set(track.channels):
            raise VispeechError(f"the track has none of the channels pose table {self.name!r} reads")
        values = track.select(self.inputs).values @ self.weights.T + self.bias
        if self.clip is not None:
            values = np.clip(values, *self.clip)
        return Track(values, self.controls, track.fps, track.start_time)


def _check_size(n_controls: int, n_inputs: int) -> None:
    if n_controls > MAX_CHANNELS or n_inputs > MAX_CHANNELS:
        raise VispeechError(
            f"a pose table may have at most {MAX_CHANNELS} controls and inputs, got {n_controls} and {n_inputs}"
        )


def _mapping(value, where: str) -> dict:
    if not isinstance(value, dict):
        raise VispeechError(f"'{where}' must be a JSON object")
    return value


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise VispeechError(f"'{where}' must be a number, got {value!r}")
    return float(value)


def _range(value) -> tuple[float, float] | None:
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 2):
        raise VispeechError("'range' must be [low, high]")
    low, high = _number(value[0], "range"), _number(value[1], "range")
    if low >= high:
        raise VispeechError(f"'range' low {low} must be below high {high}")
    return low, high
