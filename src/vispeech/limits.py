"""Every limit the library enforces, in one place, and the checks that apply them.

Each limit is checked before any work is done on an input (before a file is read, before a
model runs), so an oversized or malformed input costs a ``stat`` or a scan, not gigabytes or
minutes. A limit that is exceeded raises :class:`~vispeech.errors.VispeechError` with a
one-line message naming the limit. docs/limits.md lists them with the reasons for each value.
The server's own limits (connections, timeouts, work per message) live in ``vispeech.serve``.
"""

from __future__ import annotations

import json
import math
import numbers
import re

import numpy as np

from vispeech.errors import VispeechError

MAX_DURATION_S = 600.0
"""Seconds: the longest utterance (end of the last phone) a model is run on: 10 minutes."""

MAX_PHONES = 20_000
"""Phones: the most phones in one utterance (about 30 per second over :data:`MAX_DURATION_S`)."""

MIN_FPS = 1.0
"""Frames per second: the lowest frame rate of a track that is computed, read or resampled to."""

MAX_FPS = 240.0
"""Frames per second: the highest frame rate (the fastest Live Link / game capture rate)."""

MAX_FRAMES = int(MAX_DURATION_S * MAX_FPS)
"""Frames: the most frames in one track read from a file (:data:`MAX_DURATION_S` at :data:`MAX_FPS`)."""

MAX_CHANNELS = 1_024
"""Channels: the most curves in one track read from a file (ARKit has 52, Live Link 61)."""

MAX_TRACK_VALUE = 1e6
"""The largest magnitude of a track value read or written: blend shapes are 0 ... 1 and rotations
at most a few hundred degrees; past this a value is no motion, and 10 decimals of it (Live Link
CSV) or 6 (JSON) stay exact in a float."""

MAX_START_TIME_S = 360_000.0
"""Seconds: the largest magnitude of a track's start time (100 hours): Live Link timecodes are a
time of day, and a running counter may pass 24 h; past this a timecode is no take's."""

MAX_TEXT_CHARS = 10_000
"""Characters: the longest text ``say`` and :func:`vispeech.pipeline.speak` synthesise at once."""

MAX_FILE_BYTES = 128 * 1024 * 1024
"""Bytes: the largest text input file (alignment, animation JSON, Live Link CSV, TalkingHead JSON):
room for the Live Link CSV vispeech writes of a :data:`MAX_DURATION_S` take at :data:`MAX_FPS`."""

MAX_POSE_TABLE_BYTES = 4 * 1024 * 1024
"""Bytes: the largest pose table JSON file."""

MAX_GLB_BYTES = 512 * 1024 * 1024
"""Bytes: the largest base model (.glb) ``convert --glb`` reads."""

MAX_JSON_DEPTH = 32
"""Levels: the deepest nesting of arrays and objects in any JSON input (the formats need 4)."""

MAX_JSON_INT_DIGITS = 18
"""Digits: the longest integer literal in JSON input (anything longer is no count or index)."""

_SURROGATE = re.compile("[\ud800-\udfff]")

_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)


def check_fps(fps: float, what: str = "fps") -> float:
    """``fps`` as a float if it is a finite number within [:data:`MIN_FPS`, :data:`MAX_FPS`] (a
    string or a bool is no number here: ``"30"`` would reach the frame arithmetic as text)."""
    if isinstance(fps, bool) or not isinstance(fps, numbers.Real):
        raise VispeechError(f"{what} must be a number, got {fps!r}")
    value = float(fps)
    if value <= 0:
        raise VispeechError(f"{what} must be positive, got {fps!r}")
    if not (math.isfinite(value) and MIN_FPS <= value <= MAX_FPS):
        raise VispeechError(f"{what} must be between {MIN_FPS:g} and {MAX_FPS:g} frames per second, got {fps!r}")
    return value


def check_utterance(duration: float, n_phones: int, where: str = "") -> None:
    """Refuse an utterance longer than :data:`MAX_DURATION_S` or with more than :data:`MAX_PHONES` phones."""
    prefix = f"{where}: " if where else ""
    if not math.isfinite(duration) or duration > MAX_DURATION_S:
        raise VispeechError(f"{prefix}the utterance lasts {duration:g} s; the limit is {MAX_DURATION_S:g} s")
    if n_phones > MAX_PHONES:
        raise VispeechError(f"{prefix}the utterance has {n_phones} phones; the limit is {MAX_PHONES}")


def check_text(text: str) -> str:
    """``text`` if it has at most :data:`MAX_TEXT_CHARS` characters, all of them Unicode (:func:`check_unicode`)."""
    if len(text) > MAX_TEXT_CHARS:
        raise VispeechError(f"the text has {len(text)} characters; the limit is {MAX_TEXT_CHARS}")
    return check_unicode(text)


def check_unicode(text: str) -> str:
    """``text`` unless it holds a lone surrogate: a byte that is not UTF-8 as the shell passes
    it on (``\\xff`` becomes U+DCFF), or a ``\\udcff`` escape in JSON. No encoder takes one."""
    bad = _SURROGATE.search(text)
    if bad is None:
        return text
    code = ord(bad.group())
    byte = f" (the byte 0x{code - 0xDC00:02x}, which is not UTF-8)" if 0xDC80 <= code <= 0xDCFF else ""
    raise VispeechError(
        f"the text is not valid Unicode: lone surrogate U+{code:04X} at character {bad.start() + 1}{byte}"
    )


def check_track_range(values: np.ndarray, start_time: float, where: str = "") -> None:
    """Refuse track values (frames × channels) beyond ±:data:`MAX_TRACK_VALUE` or not finite,
    and a start time beyond ±:data:`MAX_START_TIME_S`, naming the first frame and column."""
    prefix = f"{where}: " if where else ""
    if not (math.isfinite(start_time) and abs(start_time) <= MAX_START_TIME_S):
        raise VispeechError(f"{prefix}start time {start_time:g} s is out of range (±{MAX_START_TIME_S:g} s)")
    bad = ~(np.abs(values) <= MAX_TRACK_VALUE)
    if bad.any():
        frame, column = (int(i) for i in np.argwhere(bad)[0])
        raise VispeechError(
            f"{prefix}frame {frame}, value {column} is {values[frame, column]:g}: out of range (±{MAX_TRACK_VALUE:g})"
        )


def check_track_duration(duration: float, where: str = "") -> None:
    """Refuse a track that lasts longer than :data:`MAX_DURATION_S` (``n_frames / fps`` seconds;
    to within a part in 10⁹, for durations summed from rounded frame times)."""
    if not duration <= MAX_DURATION_S * (1 + 1e-9):
        prefix = f"{where}: " if where else ""
        raise VispeechError(f"{prefix}the animation lasts {duration:g} s; the limit is {MAX_DURATION_S:g} s")


def check_track_size(n_frames: int, n_channels: int, where: str = "") -> None:
    """Refuse a track with more than :data:`MAX_FRAMES` frames or :data:`MAX_CHANNELS` channels."""
    prefix = f"{where}: " if where else ""
    if n_frames > MAX_FRAMES:
        raise VispeechError(f"{prefix}{n_frames} frames; the limit is {MAX_FRAMES}")
    if n_channels > MAX_CHANNELS:
        raise VispeechError(f"{prefix}{n_channels} channels; the limit is {MAX_CHANNELS}")


def json_depth(text: str) -> tuple[int, int]:
    """The deepest nesting of ``text`` (JSON) and the character offset where it is first reached.

    Strings are skipped, so brackets inside them do not count. Linear time, no recursion, and
    memory bounded by the chunk size beyond the text itself.
    """
    stripped = _JSON_STRING.sub('""', text)
    codes = np.frombuffer(stripped.encode("utf-8", "replace"), dtype=np.uint8)
    depth = deepest = where = 0
    chunk = 1 << 22
    for start in range(0, codes.size, chunk):
        part = codes[start : start + chunk]
        step = (part == 91).astype(np.int64) + (part == 123) - (part == 93) - (part == 125)
        running = np.cumsum(step) + depth
        i = int(np.argmax(running))
        if running[i] > deepest:
            deepest, where = int(running[i]), start + i
        depth = int(running[-1])
    return deepest, where


def parse_json(text: str, where: str) -> object:
    """Parse JSON input strictly: nesting at most :data:`MAX_JSON_DEPTH`, finite numbers only
    (no ``NaN``, ``Infinity``, ``1e999``), integers of at most :data:`MAX_JSON_INT_DIGITS` digits.

    Raises :class:`VispeechError` starting with ``where`` and saying what is wrong and where
    (line and column).
    """
    depth, _ = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise VispeechError(f"{where}: JSON nested {depth} levels deep; the limit is {MAX_JSON_DEPTH}")
    try:
        return json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float, parse_int=_bounded_int)
    except json.JSONDecodeError as exc:
        raise VispeechError(f"{where} is not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None
    except _BadNumber as exc:
        raise VispeechError(f"{where}: {exc}") from None
    except (RecursionError, ValueError, OverflowError) as exc:
        raise VispeechError(f"{where}: cannot parse JSON ({type(exc).__name__}: {exc})") from None


class _BadNumber(ValueError):
    pass


def _reject_constant(name: str):
    raise _BadNumber(f"non-finite number {name} in JSON")


def _finite_float(literal: str) -> float:
    value = float(literal)
    if not math.isfinite(value):
        raise _BadNumber(f"number {literal[:40]} is out of range")
    return value


def _bounded_int(literal: str) -> int:
    if len(literal.lstrip("-")) > MAX_JSON_INT_DIGITS:
        raise _BadNumber(f"integer of {len(literal.lstrip('-'))} digits in JSON; the limit is {MAX_JSON_INT_DIGITS}")
    return int(literal)
