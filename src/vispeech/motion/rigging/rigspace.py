"""Rig-space retargeting (Taylor et al. 2017, section 6): principal modes of the mouth, posed by an artist.

:meth:`RigSpace.fit` finds the principal modes (PCA) of a corpus's mouth channels: the mean
pose μ, orthonormal mode vectors e_k and standard deviations σ_k (square roots of the
variances), modes ordered by variance, each signed so that its largest loading is positive.
:meth:`RigSpace.reference_poses` gives the poses an artist recreates on a character rig: the
mean and, for the first modes, ``μ + u σ_k e_k`` at u = −3 and +3 (named ``mean``,
``mode1-3sd``, ``mode1+3sd``, ...). With the artist's rig poses attached
(:meth:`RigSpace.set_rig`: r_0 for the mean, r_k^u for each reference pose), a frame x
is retargeted by

- projecting it onto the modes: ``p_k = (x − μ) · e_k``;
- weighting each mode's two poses (Taylor's eq. 2): ``w_k^u = max(p_k / (u σ_k), 0)``, so at
  most one of a mode's two weights is non-zero: the one on the side of the mean p_k lies;
- summing the weighted pose offsets onto the mean rig pose (eq. 3):
  ``R = r_0 + Σ_k Σ_u w_k^u (r_k^u − r_0)``.

Each mode's coordinate is thus mapped piecewise-linearly through (−3σ_k, r_k^−3),
(0, r_0) and (+3σ_k, r_k^+3), extrapolated linearly beyond ±3σ_k; modes without rig poses
are ignored. A frame equal to a reference pose gives exactly its rig pose; the mean gives
r_0.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir, atomic_output_file, read_json
from vispeech.motion.arkit import MOUTH_CHANNELS
from vispeech.motion.track import Track

MEAN_POSE = "mean"
"""Name of the mean pose in pose sheets and rig-pose files."""

SPACE_JSON = "rigspace.json"
SPACE_ARRAYS = "modes.npz"
FORMAT = "vispeech-rigspace"
FORMAT_VERSION = 1

_POSE = re.compile(r"^mode([1-9][0-9]*)([+-][0-9]+(?:\.[0-9]+)?(?:e[+-]?[0-9]+)?)sd$")


def pose_name(mode: int, sigma: float) -> str:
    """Name of the reference pose of ``mode`` (from 1) at ``sigma`` standard deviations: ``mode1+3sd``."""
    return f"mode{mode}{sigma:+g}sd"


def parse_pose_name(name: str) -> tuple[int, float]:
    """``(mode, sigma)`` of a reference-pose name such as ``mode2-3sd``."""
    match = _POSE.match(name)
    if match is None:
        raise VispeechError(f"pose name {name!r} is neither {MEAN_POSE!r} nor like 'mode1-3sd' / 'mode1+3sd'")
    sigma = float(match.group(2))
    if sigma == 0:
        raise VispeechError(f"pose name {name!r} is at 0 standard deviations: that pose is {MEAN_POSE!r}")
    return int(match.group(1)), sigma


class RigSpace:
    """Principal modes of mouth poses and, once set, an artist's rig poses for them.

    ``channels``: the track channels the modes span (default: the
    :data:`~vispeech.motion.arkit.MOUTH_CHANNELS` every fitted track has). After
    :meth:`fit`: ``mean`` (channels,), ``modes`` (modes x channels, orthonormal rows),
    ``sd`` (modes,) and ``explained`` (modes,: each mode's share of the total variance).
    After :meth:`set_rig`: ``rig_controls``, ``rig_mean`` and ``rig_poses``
    (``{mode: {sigma: pose}}``, arrays over ``rig_controls``), ``clip``.
    """

    def __init__(self, channels: Sequence[str] | None = None) -> None:
        self.channels: tuple[str, ...] = tuple(channels or ())
        self.mean: np.ndarray | None = None
        self.modes: np.ndarray | None = None
        self.sd: np.ndarray | None = None
        self.explained: np.ndarray | None = None
        self.rig_controls: tuple[str, ...] = ()
        self.rig_mean: np.ndarray | None = None
        self.rig_poses: dict[int, dict[float, np.ndarray]] = {}
        self.clip: tuple[float, float] | None = None

    def __repr__(self) -> str:
        if self.modes is None:
            return f"RigSpace(unfitted, {len(self.channels)} channels)"
        rig = f", rig of {len(self.rig_controls)} controls on {len(self.rig_poses)} modes" if self.has_rig else ""
        return f"RigSpace({len(self.channels)} channels, {len(self.modes)} modes{rig})"

    @property
    def is_fitted(self) -> bool:
        return self.modes is not None

    @property
    def has_rig(self) -> bool:
        return self.rig_mean is not None

    # -- modes -----------------------------------------------------------------------------

    def fit(self, tracks: Iterable[Track]) -> RigSpace:
        """Principal modes of the frames of ``tracks`` (all frames pooled); returns ``self``.

        Drops any rig poses set before. Raises :class:`VispeechError` if a track lacks a
        channel or there are fewer than two frames.
        """
        tracks = list(tracks)
        if not tracks:
            raise VispeechError("no tracks to fit a rig space on")
        if not self.channels:
            self.channels = tuple(c for c in MOUTH_CHANNELS if all(c in t.channels for t in tracks))
            if not self.channels:
                raise VispeechError("the tracks share no mouth channel")
        for track in tracks:
            missing = [c for c in self.channels if c not in track.channels]
            if missing:
                raise VispeechError(f"a track lacks channels {', '.join(missing)}")
        frames = np.concatenate([t.select(self.channels).values for t in tracks])
        if len(frames) < 2:
            raise VispeechError("a rig space needs at least two frames")
        self.mean = frames.mean(axis=0)
        _, singular, vectors = np.linalg.svd(frames - self.mean, full_matrices=False)
        variance = singular**2 / (len(frames) - 1)
        keep = variance > 1e-12 * max(variance.max(), 1e-300)
        vectors, variance = vectors[keep], variance[keep]
        largest = np.argmax(np.abs(vectors), axis=1)
        vectors *= np.sign(vectors[np.arange(len(vectors)), largest])[:, None]
        self.modes, self.sd = vectors, np.sqrt(variance)
        self.explained = variance / variance.sum()
        self.rig_controls, self.rig_mean, self.rig_poses, self.clip = (), None, {}, None
        return self

    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise VispeechError("the rig space is not fitted: fit it on a corpus's tracks first")

    def project(self, track: Track) -> np.ndarray:
        """Mode coordinates ``p_k = (x − μ) · e_k`` per frame, ``(frames, modes)``.

        Channels the track lacks are taken to be at the mean (they add nothing).
        """
        self._check_fitted()
        assert self.mean is not None and self.modes is not None  # fitted
        values = np.tile(self.mean, (track.n_frames, 1))
        for j, channel in enumerate(self.channels):
            if channel in track.channels:
                values[:, j] = track[channel]
        return (values - self.mean) @ self.modes.T

    def reference_poses(self, n_modes: int = 4, sigmas: Sequence[float] = (-3.0, 3.0)) -> dict[str, np.ndarray]:
        """The mean pose and ``μ + u σ_k e_k`` for the first ``n_modes`` modes and each u in
        ``sigmas``, by name (``mean``, ``mode1-3sd``, ...), as arrays over :attr:`channels`.

        Values are exact, so they may leave [0, 1] at ±3σ.
        """
        self._check_fitted()
        assert self.mean is not None and self.modes is not None and self.sd is not None  # fitted
        if not 1 <= n_modes <= len(self.modes):
            raise VispeechError(f"n_modes must be between 1 and {len(self.modes)}, got {n_modes}")
        if any(s == 0 or not math.isfinite(s) for s in sigmas) or len(set(sigmas)) != len(sigmas):
            raise VispeechError(f"sigmas must be distinct non-zero numbers, got {list(sigmas)}")
        poses = {MEAN_POSE: self.mean.copy()}
        for k in range(n_modes):
            for sigma in sigmas:
                poses[pose_name(k + 1, sigma)] = self.mean + sigma * self.sd[k] * self.modes[k]
        return poses

    def write_pose_sheet(
        self, path: str | os.PathLike, n_modes: int = 4, sigmas: Sequence[float] = (-3.0, 3.0)
    ) -> Path:
        """Write :meth:`reference_poses` for an artist, atomically; returns ``path``.

        ``.csv``: a row per pose (``pose`` then one column per channel). Otherwise JSON:
        ``{"type": "rig-reference-poses", "channels", "modes": [{"mode", "sd", "explained"}],
        "poses": {name: {channel: value}}}``, whose ``poses`` is the layout a rig-pose file
        (:meth:`load_rig`) repeats with the rig's controls.
        """
        poses = self.reference_poses(n_modes, sigmas)
        assert self.sd is not None and self.explained is not None  # fitted: reference_poses checked
        path = Path(path)
        if path.suffix.lower() == ".csv":
            buffer = io.StringIO()
            writer = csv.writer(buffer, lineterminator="\n")
            writer.writerow(["pose", *self.channels])
            for name, pose in poses.items():
                writer.writerow([name, *(f"{v:.6f}" for v in pose)])
            text = buffer.getvalue()
        else:
            sheet = {
                "type": "rig-reference-poses",
                "channels": list(self.channels),
                "modes": [
                    {"mode": k + 1, "sd": float(self.sd[k]), "explained": float(self.explained[k])}
                    for k in range(n_modes)
                ],
                "poses": {name: dict(zip(self.channels, map(float, pose))) for name, pose in poses.items()},
            }
            text = json.dumps(sheet, indent=1) + "\n"
        with atomic_output_file(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return path

    # -- the rig ---------------------------------------------------------------------------

    def set_rig(self, poses: Mapping[str, Mapping[str, float]], clip: tuple[float, float] | None = None) -> RigSpace:
        """Attach the artist's rig poses; returns ``self``.

        ``poses[name]`` maps rig controls to values for the ``mean`` pose (required; it names
        every control) and for reference poses (``mode<k><±u>sd``); a pose leaves out the
        controls it keeps at the mean's value. Every mode given needs exactly one pose below
        and one above the mean. ``clip`` = ``(low, high)`` bounds every retargeted control.
        """
        self._check_fitted()
        assert self.modes is not None  # fitted
        if not isinstance(poses, Mapping) or MEAN_POSE not in poses:
            raise VispeechError(f"rig poses need a {MEAN_POSE!r} pose")
        mean = _pose(poses[MEAN_POSE], MEAN_POSE)
        if not mean:
            raise VispeechError(f"the {MEAN_POSE!r} rig pose names no control")
        controls = tuple(mean)
        rig_mean = np.array([mean[c] for c in controls])
        rig_poses: dict[int, dict[float, np.ndarray]] = {}
        for name, values in poses.items():
            if name == MEAN_POSE:
                continue
            mode, sigma = parse_pose_name(name)
            if mode > len(self.modes):
                raise VispeechError(f"rig pose {name!r}: the space has only {len(self.modes)} modes")
            values = _pose(values, name)
            unknown = [c for c in values if c not in mean]
            if unknown:
                raise VispeechError(f"rig pose {name!r} sets {unknown[0]!r}, which the mean pose does not name")
            sides = rig_poses.setdefault(mode, {})
            if sigma in sides:
                raise VispeechError(f"rig pose {pose_name(mode, sigma)!r} is given twice")
            sides[sigma] = np.array([values.get(c, mean[c]) for c in controls])
        for mode, sides in sorted(rig_poses.items()):
            if sorted(s > 0 for s in sides) != [False, True]:
                found = ", ".join(pose_name(mode, s) for s in sorted(sides))
                raise VispeechError(f"mode {mode} needs one rig pose below the mean and one above, got {found}")
        if clip is not None and not (len(clip) == 2 and clip[0] < clip[1]):
            raise VispeechError(f"clip must be (low, high) with low < high, got {clip}")
        self.rig_controls, self.rig_mean, self.rig_poses = controls, rig_mean, dict(sorted(rig_poses.items()))
        self.clip = None if clip is None else (float(clip[0]), float(clip[1]))
        return self

    def load_rig(self, path: str | os.PathLike) -> RigSpace:
        """Attach rig poses from a JSON file ``{"poses": {name: {control: value}}, "range": [low, high]}``
        (``range`` optional; see :meth:`set_rig`); returns ``self``."""
        data = read_json(path)
        clip = data.get("range")
        if clip is not None and not (isinstance(clip, list) and len(clip) == 2 and all(_is_number(v) for v in clip)):
            raise VispeechError(f"{path}: 'range' must be [low, high]")
        poses: Any = data.get("poses")  # JSON as read: set_rig checks it
        try:
            return self.set_rig(poses, None if clip is None else tuple(clip))
        except VispeechError as exc:
            raise VispeechError(f"{path}: {exc}") from None

    def retarget(self, track: Track) -> Track:
        """The rig-control track of ``track`` (same frames, fps and start time); see the module docstring."""
        self._check_fitted()
        if not self.has_rig:
            raise VispeechError("the rig space has no rig poses: set them from the artist's rig-pose file first")
        assert self.rig_mean is not None and self.sd is not None  # fitted, with a rig
        coordinates = self.project(track)
        out = np.tile(self.rig_mean, (track.n_frames, 1))
        for mode, sides in self.rig_poses.items():
            p = coordinates[:, mode - 1]
            for sigma, pose in sides.items():
                weight = np.maximum(p / (sigma * self.sd[mode - 1]), 0.0)
                out += weight[:, None] * (pose - self.rig_mean)
        if self.clip is not None:
            out = np.clip(out, *self.clip)
        return Track(out, self.rig_controls, track.fps, track.start_time)

    # -- saving ----------------------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write the space into folder ``path`` atomically: ``rigspace.json`` (channels, rig
        poses) and ``modes.npz`` (mean, modes, sd, explained); returns the folder."""
        self._check_fitted()
        assert self.mean is not None and self.modes is not None and self.sd is not None and self.explained is not None
        rig = None
        if self.rig_mean is not None:  # has_rig
            poses = {MEAN_POSE: dict(zip(self.rig_controls, map(float, self.rig_mean)))}
            for mode, sides in self.rig_poses.items():
                for sigma, pose in sides.items():
                    poses[pose_name(mode, sigma)] = dict(zip(self.rig_controls, map(float, pose)))
            rig = {"poses": poses, "range": None if self.clip is None else list(self.clip)}
        config = {"format": FORMAT, "version": FORMAT_VERSION, "channels": list(self.channels), "rig": rig}
        with atomic_output_dir(path) as staging:
            (staging / SPACE_JSON).write_text(json.dumps(config, indent=1) + "\n", encoding="utf-8")
            with open(staging / SPACE_ARRAYS, "wb") as handle:
                np.savez(handle, mean=self.mean, modes=self.modes, sd=self.sd, explained=self.explained)
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> RigSpace:
        """Read a folder written by :meth:`save`; raises :class:`VispeechError` if it is missing or corrupt."""
        folder = Path(path)
        if not (folder / SPACE_JSON).is_file():
            raise VispeechError(f"no rig space at {folder} ({SPACE_JSON} missing)")
        config = read_json(folder / SPACE_JSON)
        if config.get("format") != FORMAT or not isinstance(config.get("version"), int):
            raise VispeechError(f"{folder / SPACE_JSON} is not a vispeech rig space")
        if config["version"] > FORMAT_VERSION:
            raise VispeechError(
                f"{folder / SPACE_JSON} has format version {config['version']}; "
                f"this vispeech reads up to {FORMAT_VERSION}"
            )
        try:
            with np.load(folder / SPACE_ARRAYS, allow_pickle=False) as data:
                arrays = {k: np.asarray(data[k], dtype=float) for k in ("mean", "modes", "sd", "explained")}
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise VispeechError(f"cannot read {folder / SPACE_ARRAYS}: {exc}") from None
        channels = config.get("channels")
        n = len(arrays["sd"])
        if (
            not isinstance(channels, list)
            or arrays["mean"].shape != (len(channels),)
            or arrays["modes"].shape != (n, len(channels))
            or arrays["explained"].shape != (n,)
        ):
            raise VispeechError(f"{folder}: the arrays do not match the channels")
        space = cls(channels)
        space.mean, space.modes, space.sd, space.explained = (arrays[k] for k in ("mean", "modes", "sd", "explained"))
        rig = config.get("rig")
        if rig is not None:
            try:
                space.set_rig(rig.get("poses"), None if rig.get("range") is None else tuple(rig["range"]))
            except (VispeechError, AttributeError, TypeError) as exc:
                raise VispeechError(f"{folder / SPACE_JSON}: corrupt rig poses: {exc}") from None
        return space


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _pose(values, name: str) -> dict[str, float]:
    if not isinstance(values, Mapping):
        raise VispeechError(f"rig pose {name!r} must map controls to numbers")
    bad = [c for c, v in values.items() if not _is_number(v)]
    if bad:
        raise VispeechError(f"rig pose {name!r}: {bad[0]!r} is not a number")
    return {str(c): float(v) for c, v in values.items()}
