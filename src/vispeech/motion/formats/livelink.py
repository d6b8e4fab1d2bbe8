"""Live Link Face CSV: the take format of Epic's Live Link Face iPhone app.

The header is exactly the app's (61 data columns after ``Timecode`` and ``BlendshapeCount``):
the 52 ARKit shapes in PascalCase in the app's order (note ``JawRight`` before ``JawLeft`` and
``MouthRight`` before ``MouthLeft``), then head and eye rotations ``HeadYaw`` ...
``RightEyeRoll``. In a :class:`Track` every column is named by lower-casing its first letter:
``JawOpen`` -> ``jawOpen``, ``HeadYaw`` -> ``headYaw``, ``LeftEyeRoll`` -> ``leftEyeRoll``.

Timecode ``HH:MM:SS:FF.mmm`` is read as: hours, minutes, seconds, then the frame number within
the second at the timecode rate (60 for the app) and the sub-frame position in thousandths of
a frame. So ``19:16:29:35.273`` is 19 h 16 min 29 s + 35.273 / 60 s. ``Track.start_time``
is the first row's timecode in seconds since ``00:00:00:00``, which makes writing a read file
reproduce its timecodes.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, read_text
from vispeech.limits import check_fps, check_track_size
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.track import Track

_APP_ORDER = {"jawLeft": "jawRight", "jawRight": "jawLeft", "mouthLeft": "mouthRight", "mouthRight": "mouthLeft"}
"""Where the app's order differs from Apple's (:data:`~vispeech.motion.arkit.ARKIT_NAMES`): these pairs swap."""

LIVELINK_CHANNELS: tuple[str, ...] = tuple(_APP_ORDER.get(name, name) for name in ARKIT_NAMES) + (
    "headYaw",
    "headPitch",
    "headRoll",
    "leftEyeYaw",
    "leftEyePitch",
    "leftEyeRoll",
    "rightEyeYaw",
    "rightEyePitch",
    "rightEyeRoll",
)
"""Track channel names of an iPhone take's 61 value columns, in the app's order: the 52 ARKit
shapes, then head and eye rotations."""

LIVELINK_COLUMNS: tuple[str, ...] = tuple(c[0].upper() + c[1:] for c in LIVELINK_CHANNELS)
"""The 61 value columns as the app names them (``EyeBlinkLeft`` ... ``RightEyeRoll``)."""

DEFAULT_TIMECODE_RATE = 60
"""Timecode frame rate assumed when a take never crosses a second boundary and no fps is given."""

_HEADER = ("Timecode", "BlendshapeCount")
_TIMECODE = re.compile(r"^(\d{1,6}):(\d{1,2}):(\d{1,2})[:;](\d{1,6})(?:\.(\d{1,6}))?$")
_TIMECODE_RATES = (24, 25, 30, 48, 50, 60, 72, 90, 100, 120, 240)
_NOMINAL_FPS = (24, 25, 30, 48, 50, 60, 72, 90, 100, 120, 240, 24000 / 1001, 30000 / 1001, 60000 / 1001)


def write_livelink_csv(track: Track, path: str | os.PathLike, start_timecode: str = "00:00:00:00") -> None:
    """Write ``track`` as a Live Link Face CSV, one row per frame at ``track.fps``.

    Parameters
    ----------
    track : channels named as in :data:`LIVELINK_CHANNELS`; missing ones are written as 0,
        others are left out.
    path : output file, written atomically.
    start_timecode : the timecode of time 0 s; frame k gets ``start_timecode + start_time +
        k / fps``. The timecode rate is ``ceil(fps)`` frames per second.

    Values are printed with 10 decimals and ``BlendshapeCount`` is 61, as the app writes them.
    """
    rate = math.ceil(track.fps - 1e-9)
    origin = parse_timecode(start_timecode, rate, "start timecode")
    if origin + track.start_time < 0:
        raise VispeechError(f"the first frame would have a negative timecode (start time {track.start_time} s)")
    values = track.select(LIVELINK_CHANNELS).values.tolist()  # Python floats format 3x faster than numpy's
    lines = [",".join(_HEADER + LIVELINK_COLUMNS)]
    for k, row in enumerate(values):
        seconds = origin + track.start_time + k / track.fps
        fields = [_format_timecode(round(seconds * rate * 1000), rate), str(len(LIVELINK_COLUMNS))]
        fields.extend([f"{v:.10f}" for v in row])
        lines.append(",".join(fields))
    with atomic_output_file(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="")


def read_livelink_csv(path: str | os.PathLike, fps: float | None = None) -> Track:
    """Read a Live Link Face CSV (iPhone takes, vispeech's own, NeuroSync's 68-column files).

    Columns are matched by name, so any order and extra columns (NeuroSync's emotions
    ``Angry`` ... become ``angry`` ...) are accepted.

    Parameters
    ----------
    path : the CSV file.
    fps : frames per second of the rows. By default it is measured from the timecodes over
        the whole take and snapped to a nominal rate (30, 60, 29.97, ...) when within 0.01 %.
        The timecode rate comes from where the frame field wraps to the next second; a take
        shorter than that is read at 60 unless ``fps`` is given.

    Returns a :class:`Track` whose ``start_time`` is the first timecode in seconds.
    """
    path = Path(path)
    if fps is not None:
        check_fps(fps)
    lines = [line for line in read_text(path, "Live Link CSV").splitlines() if line.strip()]
    header = [name.strip() for name in lines[0].split(",")]
    if tuple(header[:2]) != _HEADER or len(header) < 3:
        raise VispeechError(f"{path} is not a Live Link Face CSV: the header must start with Timecode,BlendshapeCount")
    if not all(header[2:]):
        raise VispeechError(f"{path}, line 1: column {header.index('', 2) + 1} has no name")
    if len(set(header)) != len(header):
        twice = next(name for name in header if header.count(name) > 1)
        raise VispeechError(f"{path}, line 1: column {twice!r} appears twice")
    if not lines[1:]:
        raise VispeechError(f"Live Link CSV has no frames: {path}")
    check_track_size(len(lines) - 1, len(header) - 2, str(path))
    channels = tuple(name[0].lower() + name[1:] for name in header[2:])
    timecodes, rows = [], []
    for number, line in enumerate(lines[1:], 2):
        fields = line.split(",")
        if len(fields) != len(header):
            raise VispeechError(f"{path}, line {number}: {len(fields)} fields, the header has {len(header)}")
        match = _TIMECODE.match(fields[0].strip())
        if match is None:
            raise VispeechError(f"{path}, line {number}: bad timecode {fields[0][:40]!r}")
        timecodes.append(match.groups())
        try:
            row = [float(v) for v in fields[2:]]
        except ValueError:
            raise VispeechError(f"{path}, line {number}: a value is not a number") from None
        if not all(math.isfinite(v) for v in row):
            raise VispeechError(f"{path}, line {number}: a value is not a finite number")
        rows.append(row)
    rate = _timecode_rate(timecodes, fps)
    times = np.array([_timecode_seconds(groups, rate) for groups in timecodes])
    if np.any(np.diff(times) <= 0):
        bad = int(np.flatnonzero(np.diff(times) <= 0)[0]) + 3
        raise VispeechError(f"{path}, line {bad}: timecode does not increase")
    if fps is None:
        fps = _nominal_fps((len(times) - 1) / (times[-1] - times[0])) if len(times) > 1 else float(rate)
        check_fps(fps, f"{path}: the frame rate of the timecodes")
    try:
        return Track(np.array(rows), channels, float(fps), float(times[0]))
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None


def _timecode_rate(timecodes: list[tuple], fps: float | None) -> int:
    """Frames per second of the timecode's frame field: where it wraps, else ``ceil(fps)``."""
    max_frame = max(int(groups[3]) for groups in timecodes)
    if len({groups[:3] for groups in timecodes}) > 1:
        needed = max_frame + 1
    else:
        needed = max(max_frame + 1, DEFAULT_TIMECODE_RATE if fps is None else math.ceil(fps - 1e-9))
    return next((r for r in _TIMECODE_RATES if r >= needed), needed)


def _timecode_seconds(groups: tuple, rate: int) -> float:
    hours, minutes, seconds, frame, fraction = groups
    frames = int(frame) + (int(fraction) / 10 ** len(fraction) if fraction else 0.0)
    return int(hours) * 3600 + int(minutes) * 60 + int(seconds) + frames / rate


def parse_timecode(text: str, rate: int, what: str = "timecode") -> float:
    """Seconds of a timecode ``HH:MM:SS:FF`` (or ``;FF``, or ``:FF.mmm``) with ``rate`` frames a
    second; a :class:`VispeechError` naming ``what`` when it is not one."""
    match = _TIMECODE.match(text.strip())
    if match is None:
        raise VispeechError(f"bad {what} {text!r}: use HH:MM:SS:FF or HH:MM:SS:FF.mmm")
    return _timecode_seconds(match.groups(), rate)


def _format_timecode(milliframes: int, rate: int) -> str:
    frames, milli = divmod(milliframes, 1000)
    seconds, frame = divmod(frames, rate)
    hours, rest = divmod(seconds, 3600)
    minutes, seconds = divmod(rest, 60)
    return f"{hours:02d}:{minutes:02d}:{seconds:02d}:{frame:02d}.{milli:03d}"


def _nominal_fps(measured: float) -> float:
    nearest = min(_NOMINAL_FPS, key=lambda f: abs(f - measured))
    return float(nearest) if abs(nearest - measured) <= 1e-4 * measured else float(measured)
