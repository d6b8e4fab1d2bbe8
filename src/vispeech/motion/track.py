"""The animation track: frames x named channels at a frame rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE
from vispeech.errors import VispeechError


@dataclass
class Track:
    """Animation curves: ``values[frame, channel]`` sampled at ``fps``.

    Frame k sits at ``start_time + k / fps`` seconds. Channel names are ARKit names
    (``jawOpen``, ``mouthClose``, ...) unless a retargeting says otherwise.
    """

    values: np.ndarray
    channels: tuple[str, ...]
    fps: float
    start_time: float = 0.0

    def __post_init__(self) -> None:
        self.values = np.asarray(self.values, dtype=np.float64)
        self.channels = tuple(self.channels)
        self.validate()

    @classmethod
    def zeros(cls, n_frames: int, channels, fps: float, start_time: float = 0.0) -> Track:
        return cls(np.zeros((n_frames, len(tuple(channels)))), tuple(channels), fps, start_time)

    @property
    def n_frames(self) -> int:
        return self.values.shape[0]

    @property
    def duration(self) -> float:
        """Seconds covered: ``n_frames / fps``."""
        return self.n_frames / self.fps

    @property
    def times(self) -> np.ndarray:
        """Time of each frame in seconds."""
        return self.start_time + np.arange(self.n_frames) / self.fps

    def validate(self) -> Track:
        """Raise :class:`VispeechError` on a wrong shape, duplicate names, bad fps or non-finite values."""
        if self.values.ndim != 2:
            raise VispeechError(f"track values must be 2-D (frames x channels), got shape {self.values.shape}")
        if self.values.shape[1] != len(self.channels):
            raise VispeechError(f"track has {self.values.shape[1]} columns but {len(self.channels)} channel names")
        if len(set(self.channels)) != len(self.channels):
            raise VispeechError("track channel names are not unique")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise VispeechError(f"track fps must be positive, got {self.fps}")
        if not np.isfinite(self.start_time):
            raise VispeechError(f"track start time must be a number of seconds, got {self.start_time}")
        if not np.all(np.isfinite(self.values)):
            raise VispeechError("track has non-finite values")
        return self

    def index(self, channel: str) -> int:
        try:
            return self.channels.index(channel)
        except ValueError:
            raise VispeechError(f"track has no channel {channel!r}") from None

    def __getitem__(self, channel: str) -> np.ndarray:
        """The curve of one channel (a view)."""
        return self.values[:, self.index(channel)]

    def get(self, channel: str, default: float = 0.0) -> np.ndarray:
        """The curve of ``channel``, or a constant ``default`` curve if the track lacks it."""
        if channel in self.channels:
            return self[channel]
        return np.full(self.n_frames, default)

    def copy(self) -> Track:
        return Track(self.values.copy(), self.channels, self.fps, self.start_time)

    def select(self, channels) -> Track:
        """A track with exactly ``channels`` in that order; channels it lacks are zero."""
        channels = tuple(channels)
        position = {name: i for i, name in enumerate(self.channels)}
        found = [(j, position[name]) for j, name in enumerate(channels) if name in position]
        out = np.zeros((self.n_frames, len(channels)))
        if found:
            into, source = zip(*found)
            out[:, list(into)] = self.values[:, list(source)]
        return Track(out, channels, self.fps, self.start_time)

    def resample(self, fps: float, n_frames: int | None = None) -> Track:
        """Linear interpolation to another frame rate, same start time and duration (frames past
        the last one hold its values)."""
        if not (np.isfinite(fps) and fps > 0):
            raise VispeechError(f"fps must be positive, got {fps}")
        if n_frames is not None and n_frames < 1:
            raise VispeechError(f"a resampled track needs 1 frame or more, got n_frames={n_frames}")
        n = n_frames if n_frames is not None else max(1, int(round(self.duration * fps)))
        return Track(
            interpolate_rows(self.values, np.arange(n) * (self.fps / fps)), self.channels, fps, self.start_time
        )

    def slice(self, start: float, end: float) -> Track:
        """Frames whose time lies in ``[start, end)`` seconds."""
        t = self.times
        keep = (t >= start - TIME_TOLERANCE) & (t < end - TIME_TOLERANCE)
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            raise VispeechError(f"no frames between {start} s and {end} s")
        return Track(self.values[idx], self.channels, self.fps, float(t[idx[0]]))

    def to_dict(self) -> dict:
        """JSON-ready form: ``{"fps", "start_time", "channels", "frames": [[...], ...]}``."""
        return {
            "fps": self.fps,
            "start_time": self.start_time,
            "n_frames": self.n_frames,
            "channels": list(self.channels),
            "frames": np.round(self.values, 6).tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> Track:
        """Inverse of :meth:`to_dict`; raises :class:`VispeechError` on a malformed dict."""
        try:
            channels = tuple(str(c) for c in data["channels"])
            frames = np.asarray(data["frames"], dtype=float).reshape(-1, len(channels))
            if "n_frames" in data and data["n_frames"] != len(frames):
                raise ValueError(f"n_frames is {data['n_frames']} but there are {len(frames)} frames")
            return cls(frames, channels, float(data["fps"]), float(data.get("start_time", 0.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise VispeechError(f"malformed track: {exc}") from None


def interpolate_rows(values: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Rows (len(positions) × columns) of ``values`` (rows × columns, at least one row) at
    fractional row ``positions``: linear between neighbours, clamped to the first and last row."""
    position = np.clip(positions, 0.0, len(values) - 1)
    if len(values) == 1:
        return np.repeat(values, len(position), axis=0)
    lo = np.minimum(position.astype(np.intp), len(values) - 2)
    return values[lo] + (position - lo)[:, None] * (values[lo + 1] - values[lo])
