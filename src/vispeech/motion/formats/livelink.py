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

import itertools
import math
import os
import re
import statistics
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, read_text
from vispeech.limits import (
    MAX_START_TIME_S,
    MAX_TRACK_VALUE,
    check_fps,
    check_track_duration,
    check_track_range,
    check_track_size,
)
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

_ROUNDING = 1e-3
"""Seconds: more than a timecode's rounding to thousandths of a frame, kept below
:data:`~vispeech.limits.MAX_START_TIME_S` by the writer so that the reader takes what it writes."""
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
    Values and start time out of the range :func:`read_livelink_csv` reads
    (:func:`~vispeech.limits.check_track_range`) are refused.
    """
    text = _texts([_frames(track, start_timecode, f"cannot write {path}")])[0]
    with atomic_output_file(path) as tmp:
        tmp.write_bytes(text)


def livelink_csv_texts(tracks: Sequence[Track], start_timecode: str = "00:00:00:00") -> list[bytes | VispeechError]:
    """What :func:`write_livelink_csv` writes for each of ``tracks``, byte for byte, formatted
    together (the frames of all of them in one pass): the file's bytes, or for a track it refuses
    (values or start out of range) the :class:`VispeechError`."""
    results: list[bytes | VispeechError] = []
    frames = []
    for track in tracks:
        try:
            frames.append(_frames(track, start_timecode, "cannot write a Live Link CSV"))
            results.append(b"")
        except VispeechError as exc:
            results.append(exc)
    texts = iter(_texts(frames))
    return [next(texts) if isinstance(result, bytes) else result for result in results]


_Frames = tuple[np.ndarray, int, np.ndarray]
"""A track's rows to write: each frame's timecode in thousandths of a timecode frame, the
timecode rate, and the values in the columns of :data:`LIVELINK_CHANNELS`."""


def _frames(track: Track, start_timecode: str, what: str) -> _Frames:
    """``track``'s :data:`_Frames`, refused (``what`` leading the message) out of range."""
    check_track_range(track.values, track.start_time, what)
    rate = math.ceil(track.fps - 1e-9)
    origin = parse_timecode(start_timecode, rate, "start timecode")
    if not 0 <= origin + track.start_time <= MAX_START_TIME_S - _ROUNDING:
        raise VispeechError(
            f"{what}: the first frame's timecode would be {origin + track.start_time:g} s;"
            f" it must be 0 ... {MAX_START_TIME_S - _ROUNDING:g} s"
        )
    seconds = origin + track.start_time + np.arange(track.n_frames) / track.fps
    return np.rint(seconds * rate * 1000).astype(np.int64), rate, _columns(track)


def _texts(frames: list[_Frames]) -> list[bytes]:
    """The CSV files of ``frames``, those of one timecode rate formatted together."""
    header = (",".join(_HEADER + LIVELINK_COLUMNS) + "\n").encode("ascii")
    texts = [header] * len(frames)
    for rate in sorted({f[1] for f in frames}):
        group = [k for k, f in enumerate(frames) if f[1] == rate]
        milliframes, columns = (np.concatenate([frames[k][part] for k in group]) for part in (0, 2))
        chars, lengths = _rows(milliframes, rate, columns)
        rows = np.cumsum([0] + [len(frames[k][0]) for k in group])  # each track's first row, and the end
        bounds = np.concatenate(([0], np.cumsum(lengths)))[rows].tolist()  # the same in bytes
        for k, start, end in zip(group, bounds, bounds[1:]):
            texts[k] = header + chars[start:end]
    return texts


def _columns(track: Track) -> np.ndarray:
    """The track's values in the columns of :data:`LIVELINK_CHANNELS` (frames × 61), 0 where it lacks one."""
    position = {name: i for i, name in enumerate(track.channels)}
    found = [(j, position[name]) for j, name in enumerate(LIVELINK_CHANNELS) if name in position]
    values = np.zeros((track.n_frames, len(LIVELINK_CHANNELS)))
    if found:
        into, source = zip(*found)
        values[:, list(into)] = track.values[:, list(source)]
    return values


_Text = tuple[np.ndarray, np.ndarray | None]
"""ASCII text laid out in columns: bytes (rows × width, uint8) and which of them are written
(``None``: all of them)."""

_PLACES = 10
"""Decimals of the values, as the app writes them."""


def _rows(milliframes: np.ndarray, rate: int, values: np.ndarray) -> tuple[bytes, np.ndarray]:
    """Every frame's line, ``HH:MM:SS:FF.mmm,61,`` and the values with :data:`_PLACES` decimals,
    and each line's length in bytes.

    Made for all frames at once: each field takes a column of bytes as wide as its widest
    value, and the zero-padding no value asked for is left out (``%02d`` hours past 99), so a
    line's text is its own whatever the other lines."""
    n = len(values)
    frames, milli = np.divmod(milliframes, 1000)
    seconds, frame = np.divmod(frames, rate)
    hours, seconds = np.divmod(seconds, 3600)
    minutes, seconds = np.divmod(seconds, 60)
    colon = _literal(":", n)
    timecode = [_digits(hours, 2), colon, _digits(minutes, 2), colon, _digits(seconds, 2), colon, _digits(frame, 2)]
    timecode += [_literal(".", n), _digits(milli, 3)]
    chars, keep = _join([*timecode, _literal(f",{len(LIVELINK_COLUMNS)}", n), _fixed_point(values), _literal("\n", n)])
    if keep is None:
        return chars.tobytes(), np.full(n, chars.shape[1])
    return chars[keep].tobytes(), keep.sum(axis=1)


def _fixed_point(values: np.ndarray) -> _Text:
    """``,%.10f`` of every value (rows × columns) as Python prints it: the magnitude rounded to
    :data:`_PLACES` decimals (half to even, from its exact binary value), ``-`` where the sign
    bit is set. One row of text per row of values."""
    n, columns = values.shape
    magnitude = np.abs(values).reshape(-1)
    scaled = magnitude * 10**_PLACES  # at most 1e16 (MAX_TRACK_VALUE): within int64
    exact = (np.abs(scaled - np.floor(scaled) - 0.5) > np.spacing(scaled)) & (scaled < 2**52)
    units = np.where(exact, np.rint(scaled), 0.0).astype(np.int64)
    for i in np.flatnonzero(~exact).tolist():  # too near a tie to trust the product, or past 2**52
        units[i] = int(f"{magnitude[i]:.{_PLACES}f}".replace(".", ""))
    digits, shown = _digits(units, _PLACES + 1)
    point = digits.shape[1] - _PLACES
    fields = [_literal(",", len(units)), (digits[:, :point], None if shown is None else shown[:, :point])]
    fields += [_literal(".", len(units)), (digits[:, point:], None)]
    sign = np.signbit(values).reshape(-1, 1)
    if sign.any():
        fields.insert(1, (np.where(sign, ord("-"), 0).astype(np.uint8), sign))
    chars, keep = _join(fields)
    width = columns * chars.shape[1]
    return chars.reshape(n, width), None if keep is None else keep.reshape(n, width)


def _digits(numbers: np.ndarray, at_least: int) -> _Text:
    """``%0{at_least}d`` of non-negative integers (one row each), four digits at a time."""
    width = max(at_least, len(str(numbers.max())) if len(numbers) else 0)
    groups = -(-width // 4)
    quads = np.empty((len(numbers), groups), dtype=np.uint32)
    table, rest = _four_digits(), numbers
    for g in range(groups - 1, -1, -1):
        quad = rest % 10_000
        rest = rest // 10_000
        quads[:, g] = table[quad.astype(np.intp)]
    chars = quads.view(np.uint8)[:, 4 * groups - width :]
    if width == at_least:
        return chars, None
    shown = np.searchsorted(10 ** np.arange(1, width, dtype=np.int64), numbers, side="right") + 1
    return chars, np.arange(width) >= width - np.maximum(shown, at_least)[:, None]


@cache
def _four_digits() -> np.ndarray:
    """``%04d`` of 0 ... 9999 as four ASCII bytes each (made on the first write, not at import)."""
    digits = np.arange(10_000)[:, None] // np.array([1000, 100, 10, 1]) % 10 + ord("0")
    return digits.astype(np.uint8).view(np.uint32)[:, 0]


def _literal(text: str, n: int) -> _Text:
    """The same ASCII ``text`` on each of ``n`` rows."""
    return np.broadcast_to(np.frombuffer(text.encode("ascii"), dtype=np.uint8), (n, len(text))), None


def _join(parts: list[_Text]) -> _Text:
    """Texts side by side, row by row."""
    chars = np.concatenate([c for c, _ in parts], axis=1)
    if all(keep is None for _, keep in parts):
        return chars, None
    return chars, np.concatenate([np.ones(c.shape, bool) if keep is None else keep for c, keep in parts], axis=1)


def read_livelink_csv(path: str | os.PathLike, fps: float | None = None) -> Track:
    """Read a Live Link Face CSV (iPhone takes, vispeech's own, NeuroSync's 68-column files).

    Columns are matched by name, so any order and extra columns (NeuroSync's emotions
    ``Angry`` ... become ``angry`` ...) are accepted.

    Parameters
    ----------
    path : the CSV file.
    fps : frames per second of the rows. By default it is measured from the timecodes over
        the whole take and snapped to a nominal rate (30, 60, 29.97, ...) or a whole number when
        within 0.01 %.
        The timecode rate comes from where the frame field wraps to the next second; a take
        shorter than that is read at 60 unless ``fps`` is given.

    Returns a :class:`Track` whose ``start_time`` is the first timecode in seconds.
    """
    path = Path(path)
    if fps is not None:
        check_fps(fps)
    lines = [line for line in read_text(path, "Live Link CSV").splitlines() if line.strip()]
    header = [name.strip() for name in lines[0].split(",")]
    if tuple(name.lower() for name in header[:2]) != tuple(name.lower() for name in _HEADER) or len(header) < 3:
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
        wild = next((j for j, v in enumerate(row) if not abs(v) <= MAX_TRACK_VALUE), None)
        if wild is not None:
            raise VispeechError(
                f"{path}, line {number}: {header[wild + 2]} is {fields[wild + 2].strip()[:40]},"
                f" not a finite number within ±{MAX_TRACK_VALUE:g}"
            )
        rows.append(row)
    rate = _timecode_rate(timecodes, fps)
    times = np.array([_timecode_seconds(groups, rate) for groups in timecodes])
    if not times[0] <= MAX_START_TIME_S:
        first = lines[1].split(",")[0].strip()
        raise VispeechError(f"{path}, line 2: timecode {first} is past {MAX_START_TIME_S / 3600:g} hours")
    if np.any(np.diff(times) <= 0):
        bad = int(np.flatnonzero(np.diff(times) <= 0)[0]) + 3
        raise VispeechError(f"{path}, line {bad}: timecode does not increase")
    if fps is None:
        fps = _nominal_fps((len(times) - 1) / (times[-1] - times[0]), rate) if len(times) > 1 else float(rate)
        check_fps(fps, f"{path}: the frame rate of the timecodes")
    check_track_duration(len(rows) / fps, str(path))
    try:
        return Track(np.array(rows), channels, float(fps), float(times[0]))
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None


def _timecode_rate(timecodes: list[tuple], fps: float | None) -> int:
    """Frames per second of the timecode's frame field. ``ceil(fps)`` when ``fps`` is given and
    the frame numbers fit it. Where the field wraps to the next second: the highest frame
    number + 1, or the nominal rate just above it when the frame numbers the take never shows at
    a second's end are fewer than its rows' usual step (rows every 5th frame of a 60 fps
    timecode end at 55: 60). A take that never wraps: :data:`DEFAULT_TIMECODE_RATE`, or the
    nominal rate above its highest frame number when it has more."""
    frames = [int(groups[3]) for groups in timecodes]
    needed = max(frames) + 1
    if fps is not None and math.ceil(fps - 1e-9) >= needed:
        return math.ceil(fps - 1e-9)
    seconds = [groups[:3] for groups in timecodes]
    if len(set(seconds)) == 1:
        return DEFAULT_TIMECODE_RATE if fps is None and needed <= DEFAULT_TIMECODE_RATE else _nominal_rate(needed)
    steps = [b - a for (sa, a), (sb, b) in itertools.pairwise(zip(seconds, frames)) if sa == sb and b > a]
    step = statistics.median(steps) if steps else 1
    return next((r for r in _TIMECODE_RATES if needed <= r < needed + step), needed)


def _nominal_rate(needed: int) -> int:
    """The lowest nominal timecode rate of ``needed`` frames a second or more (else ``needed``)."""
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


def _nominal_fps(measured: float, rate: int) -> float:
    nearest = min((*_NOMINAL_FPS, rate, round(measured)), key=lambda f: abs(f - measured))
    return float(nearest) if abs(nearest - measured) <= 1e-4 * measured else float(measured)
