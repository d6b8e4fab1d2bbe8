"""JSON animation files: vispeech's own form and TalkingHead's blend-shape animation.

vispeech animation JSON (values rounded to 6 decimals)::

    {"format": "vispeech-animation", "version": 1, "fps": 30.0, "start_time": 0.0,
     "n_frames": 2, "channels": ["jawOpen", ...], "frames": [[0.1, ...], [0.2, ...]],
     "phones": {...PhoneSequence.to_dict()...},      # optional
     "audio": "hello.wav"}                             # optional

TalkingHead (met4citizen/TalkingHead) ``playAnimation`` blend-shape form, ``dt`` in
milliseconds per frame::

    {"name": "blendshapes", "dt": [33.333, ...], "vs": {"jawOpen": [0.1, ...], ...}}
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from vispeech.alignment.formats import phones_from_dict
from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, read_json
from vispeech.limits import check_fps, check_track_duration, check_track_range, check_track_size, check_utterance
from vispeech.motion.track import Track

ANIMATION_FORMAT: Final = "vispeech-animation"
"""The ``format`` tag of vispeech animation JSON."""


@dataclass
class Animation:
    """A track with the phones and audio file name a file holds besides (as vispeech animation
    JSON may; :func:`vispeech.motion.formats.registry.read_animation` reads any format as one)."""

    track: Track
    phones: PhoneSequence | None = None
    audio: str | None = None


def write_animation_json(
    track: Track,
    path: str | os.PathLike,
    *,
    phones: PhoneSequence | None = None,
    audio: str | None = None,
) -> None:
    """Write ``track`` (and optionally its phones and audio file name) as vispeech JSON, atomically;
    refused (:class:`VispeechError`) where :func:`read_animation_json` would refuse it."""
    check_track_range(track.values, track.start_time, f"cannot write {path}")
    if phones is not None:
        try:
            check_utterance(phones.duration, len(phones))
            phones.validate()
        except VispeechError as exc:
            raise VispeechError(f"cannot write {path}: {exc}") from None
    data = {"format": ANIMATION_FORMAT, "version": 1, **track.to_dict()}
    if phones is not None:
        data["phones"] = phones.to_dict()
    if audio is not None:
        data["audio"] = str(audio)
    _write_json(data, path)


def read_animation_json(path: str | os.PathLike) -> Animation:
    """Read a vispeech animation JSON file; raises :class:`VispeechError` naming what is wrong."""
    path = Path(path)
    data = read_json(path)
    if data.get("format") != ANIMATION_FORMAT:
        raise VispeechError(f"{path} is not a {ANIMATION_FORMAT} file (its format is {data.get('format')!r})")
    if data.get("version") != 1:
        raise VispeechError(f"{path}: unsupported {ANIMATION_FORMAT} version {data.get('version')!r}")
    for key in ("fps", "channels", "frames"):
        if key not in data:
            raise VispeechError(f"{path}: missing {key!r}")
    frames, channels = data["frames"], data["channels"]
    if not isinstance(channels, list) or not isinstance(frames, list) or not frames or not channels:
        raise VispeechError(f"{path}: 'channels' and 'frames' must be non-empty lists")
    unnamed = next((c for c in channels if not isinstance(c, str) or not c), None)
    if unnamed is not None:
        raise VispeechError(f"{path}: a channel's name must be non-empty text, got {_excerpt(unnamed)}")
    for i, row in enumerate(frames):
        if not isinstance(row, list) or len(row) != len(channels):
            raise VispeechError(f"{path}: frame {i} does not have {len(channels)} values")
    if "n_frames" in data and data["n_frames"] != len(frames):
        raise VispeechError(f"{path}: n_frames is {data['n_frames']} but there are {len(frames)} frames")
    check_track_size(len(frames), len(channels), str(path))
    if isinstance(data["fps"], bool) or not isinstance(data["fps"], (int, float)):
        raise VispeechError(f"{path}: 'fps' must be a number, got {data['fps']!r}")
    check_fps(data["fps"], f"{path}: fps")
    check_track_duration(len(frames) / data["fps"], str(path))
    start_time = data.get("start_time", 0.0)
    if isinstance(start_time, bool) or not isinstance(start_time, (int, float)):
        raise VispeechError(f"{path}: 'start_time' must be a number, got {start_time!r}")
    for i, row in enumerate(frames):
        for j, value in enumerate(row):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise VispeechError(f"{path}: frame {i}, value {j} is not a number ({_excerpt(value)})")
    if data.get("phones") is not None and not isinstance(data["phones"], dict):
        raise VispeechError(f"{path}: 'phones' must be an object")
    try:
        track = Track.from_dict(data)
        check_track_range(track.values, track.start_time)
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None
    phones = phones_from_dict(data["phones"], f"{path}: phones") if data.get("phones") is not None else None
    audio = data.get("audio")
    return Animation(track, phones, None if audio is None else str(audio))


def write_talkinghead_json(track: Track, path: str | os.PathLike, name: str = "blendshapes") -> None:
    """Write ``track`` in TalkingHead's ``{"name", "dt", "vs"}`` form (atomically).

    ``dt`` holds ``1000 / fps`` ms for every frame; values are rounded to 6 decimals. Values
    out of the range :func:`read_talkinghead_json` reads are refused.
    """
    check_track_range(track.values, 0.0, f"cannot write {path}")
    dt = [1000.0 / track.fps] * track.n_frames
    vs = {c: np.round(track.values[:, j], 6).tolist() for j, c in enumerate(track.channels)}
    _write_json({"name": name, "dt": dt, "vs": vs}, path)


def read_talkinghead_json(path: str | os.PathLike, fps: float | None = None) -> Track:
    """Read TalkingHead's blend-shape animation (bare or wrapped as ``{"anim": {...}}``).

    Frame i lasts ``dt[i]`` ms. Equal ``dt`` give ``fps = 1000 / dt``; unequal ones are
    resampled linearly at ``fps`` (default: ``1000 / median(dt)``).
    """
    path = Path(path)
    data = read_json(path)
    data = data.get("anim", data) if isinstance(data.get("anim"), dict) else data
    dt, vs = data.get("dt"), data.get("vs")
    if not isinstance(dt, list) or not isinstance(vs, dict) or not dt or not vs:
        raise VispeechError(f"{path} is not a TalkingHead animation: it needs non-empty 'dt' and 'vs'")
    check_track_size(len(dt), len(vs), str(path))
    for name, values in (("dt", dt), *(("vs." + str(k), v) for k, v in vs.items())):
        if not isinstance(values, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
        ):
            raise VispeechError(f"{path}: '{name}' must be a list of numbers")
    if fps is not None:
        check_fps(fps)
    durations = np.asarray(dt, dtype=float)
    curves = {str(name): np.asarray(values, dtype=float) for name, values in vs.items()}
    if durations.ndim != 1 or np.any(~np.isfinite(durations)) or np.any(durations <= 0):
        raise VispeechError(f"{path}: every 'dt' must be a positive number of milliseconds")
    for name, values in curves.items():
        if values.shape != durations.shape:
            raise VispeechError(f"{path}: 'vs.{name}' has {values.size} values for {durations.size} frames")
    if len(curves) != len(vs):
        raise VispeechError(f"{path}: two 'vs' curves have the same name")
    channels = tuple(curves)
    values = np.stack([curves[c] for c in channels], axis=1)
    check_track_range(values, 0.0, str(path))
    uniform = np.allclose(durations, durations[0], rtol=1e-9, atol=0.0)
    rate = fps if fps is not None else 1000.0 / float(np.median(durations))
    rate = round(rate, 6) if abs(rate - round(rate, 6)) < 1e-9 else rate
    check_fps(rate, f"{path}: the frame rate (1000 / dt)")
    check_track_duration(float(durations.sum()) / 1000.0, str(path))
    try:
        if uniform:
            return Track(values, channels, rate)
        starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]]) / 1000.0
        n = max(1, int(round(durations.sum() / 1000.0 * rate)))
        grid = np.arange(n) / rate
        resampled = np.stack([np.interp(grid, starts, values[:, j]) for j in range(len(channels))], axis=1)
        return Track(resampled, channels, rate)
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None


def _excerpt(value: object, width: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= width else text[:width] + "..."


def _write_json(data: dict, path: str | os.PathLike) -> None:
    with atomic_output_file(path) as tmp:
        tmp.write_text(json.dumps(data, separators=(",", ":")) + "\n", encoding="utf-8")
