"""Talking-face video in: its sound, and the face tracked in every frame.

:func:`track_face` decodes a video file (PyAV) and runs MediaPipe Face Landmarker on each frame
in VIDEO mode (timestamps from the frame times), as the GRID corpus's tracks were made
(``shared/data/grid_s1/README.md``): per frame the 51 ARKit blend-shape scores (MediaPipe's
names, no ``tongueOut``), the head pose from the facial transformation matrix (``headYaw``,
``headPitch``, ``headRoll`` in degrees; ``headX``, ``headY``, ``headZ`` in centimetres, camera
space) and 19 landmarks of the 478-point mesh (:data:`LANDMARKS`, image-normalised x and y, z
on x's scale). A frame where no face is found is NaN throughout: marked, never invented.
:func:`video_audio` gives the sound track as 16 kHz mono.

MediaPipe and PyAV are the ``capture`` extra. The face model file is never downloaded: it is
the path given, else :data:`FACE_MODEL_VARIABLE`'s, else the one vispeech ships
(:data:`SHIPPED_FACE_MODEL`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.limits import MAX_DURATION_S

FACE_MODEL_VARIABLE = "VISPEECH_FACE_MODEL"
"""The environment variable naming the MediaPipe face landmarker model (``face_landmarker.task``)."""

SHIPPED_FACE_MODEL = Path(__file__).parent / "data" / "face_landmarker.task"
"""MediaPipe's Face Landmarker model bundle as Google publishes it (face detector, 478-point
mesh, 52 blend-shape scores; Apache License 2.0: ``LICENSE-MediaPipe.txt`` beside it): the
tracker that made grid_s1's face tracks."""

LANDMARKS: tuple[int, ...] = (13, 14, 78, 308, 0, 17, 61, 291, 37, 267, 84, 314, 152, 148, 377, 1, 33, 263, 10)
"""The mesh points kept, as in GRID's tracks: inner lips (13, 14), inner and outer mouth corners
(78, 308, 61, 291), outer lips (0, 17, 37, 267, 84, 314), chin and jaw (152, 148, 377), nose tip
(1), outer eye corners (33, 263), forehead (10)."""

HEAD_CHANNELS: tuple[str, ...] = ("headYaw", "headPitch", "headRoll", "headX", "headY", "headZ")
"""Head pose channels: rotation in degrees, position in centimetres (camera space)."""

SAMPLE_RATE = 16_000
"""The rate :func:`video_audio` resamples to (Hz), the corpus's."""


@dataclass(frozen=True)
class FaceTrack:
    """The face in every frame of a video: ``values`` (frames × :attr:`channels`: blend-shape
    scores, then :data:`HEAD_CHANNELS`), ``landmarks`` (frames × :data:`LANDMARKS` × 3), both NaN
    where no face was found; the video's ``fps`` and frame ``size`` (width, height) in pixels."""

    values: np.ndarray
    channels: tuple[str, ...]
    landmarks: np.ndarray
    fps: float
    size: tuple[int, int]

    @property
    def found(self) -> np.ndarray:
        """Per frame, whether a face was found."""
        return np.isfinite(self.values).all(axis=1)


def check_installed() -> None:
    """Import PyAV and MediaPipe (the ``capture`` extra) now, so that a missing one is a
    ``ModuleNotFoundError`` before any work."""
    import av  # noqa: F401
    import mediapipe  # noqa: F401


def face_model_path(path: str | os.PathLike | None = None) -> Path:
    """The face landmarker model: ``path``, else :data:`FACE_MODEL_VARIABLE`'s, else
    :data:`SHIPPED_FACE_MODEL`; a :class:`VispeechError` when that is not a file."""
    chosen = path or os.environ.get(FACE_MODEL_VARIABLE) or SHIPPED_FACE_MODEL
    if not Path(chosen).is_file():
        raise VispeechError(f"face model not found: {chosen}")
    return Path(chosen)


def _open(path: str | os.PathLike):
    import av

    if not Path(path).is_file():
        raise VispeechError(f"video not found: {path}")
    try:
        return av.open(str(path))
    except (av.error.FFmpegError, UnicodeDecodeError, ValueError) as exc:
        raise VispeechError(f"{path}: not a video file vispeech can read ({_reason(exc)})") from None


def _reason(exc: Exception) -> str:
    """FFmpeg's words for an error, without its error number."""
    return str(getattr(exc, "strerror", None) or exc).strip()


def video_audio(path: str | os.PathLike) -> AudioClip:
    """The video's sound track, mixed to mono and resampled to :data:`SAMPLE_RATE`; a
    :class:`VispeechError` when it has none or it cannot be decoded."""
    import av

    with _open(path) as container:
        if not container.streams.audio:
            raise VispeechError(f"{path} has no audio track")
        resampler = av.AudioResampler(format="s16", layout="mono", rate=SAMPLE_RATE)
        chunks = []
        try:
            for frame in container.decode(audio=0):
                chunks += [f.to_ndarray().reshape(-1) for f in resampler.resample(frame)]
            chunks += [f.to_ndarray().reshape(-1) for f in resampler.resample(None)]
        except av.error.FFmpegError as exc:
            raise VispeechError(f"{path}: cannot decode its audio ({_reason(exc)})") from None
    if not chunks:
        raise VispeechError(f"{path}: its audio track is empty")
    return AudioClip.from_array(np.concatenate(chunks), SAMPLE_RATE, where=f"{path}'s audio")


def video_timecode(path: str | os.PathLike) -> tuple[str, float] | None:
    """The video's start timecode (``HH:MM:SS:FF``, as QuickTime's timecode track or the
    container's metadata holds it) and its video frame rate, or None when it has none."""
    with _open(path) as container:
        video = container.streams.video[0] if container.streams.video else None
        for metadata in [*(s.metadata for s in container.streams), container.metadata]:
            if metadata.get("timecode"):
                rate = float(video.average_rate or 0) if video is not None else 0.0
                return metadata["timecode"], rate
    return None


def track_face(
    path: str | os.PathLike,
    face_model: str | os.PathLike | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FaceTrack:
    """Track the face in every frame of the video at ``path`` (see the module docstring).
    ``progress(done, total)`` is called after each frame. Raises :class:`VispeechError` for a
    file without a readable video stream, one longer than the audio limit, or no face in any
    frame."""
    import av
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    model = face_model_path(face_model)
    with _open(path) as container:
        if not container.streams.video:
            raise VispeechError(f"{path} has no video stream")
        stream = container.streams.video[0]
        fps = float(stream.average_rate or stream.guessed_rate or 0)
        if not fps > 0:
            raise VispeechError(f"{path}: its video stream has no frame rate")
        duration = float(container.duration / av.time_base) if container.duration else 0.0
        if duration > MAX_DURATION_S:
            raise VispeechError(f"{path} lasts {duration:.1f} s; the limit is {MAX_DURATION_S:g} s")
        total = stream.frames or round(duration * fps)
        options = vision.FaceLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(model)),
            running_mode=vision.RunningMode.VIDEO,
            num_faces=1,
            output_face_blendshapes=True,
            output_facial_transformation_matrixes=True,
        )
        names: list[str] | None = None
        rows: list[np.ndarray | None] = []  # None: no face in the frame
        points: list[np.ndarray | None] = []
        size = (stream.codec_context.width, stream.codec_context.height)
        landmarker = vision.FaceLandmarker.create_from_options(options)
        try:
            for index, frame in enumerate(container.decode(video=0)):
                image = np.ascontiguousarray(frame.to_ndarray(format="rgb24"))  # MediaPipe needs packed rows
                size = (image.shape[1], image.shape[0])
                found = landmarker.detect_for_video(
                    mp.Image(image_format=mp.ImageFormat.SRGB, data=image), round(index * 1000 / fps)
                )
                if found.face_blendshapes:
                    scores = [c for c in found.face_blendshapes[0] if c.category_name != "_neutral"]
                    names = names or [c.category_name for c in scores]
                    pose = _head_pose(np.asarray(found.facial_transformation_matrixes[0]))
                    rows.append(np.array([c.score for c in scores] + pose))
                    mesh = found.face_landmarks[0]
                    points.append(np.array([[mesh[k].x, mesh[k].y, mesh[k].z] for k in LANDMARKS]))
                else:
                    rows.append(None)
                    points.append(None)
                if progress is not None:
                    progress(index + 1, max(total, index + 1))
        except av.error.FFmpegError as exc:
            raise VispeechError(f"{path}: cannot decode its video ({_reason(exc)})") from None
        finally:
            landmarker.close()
    if names is None:
        raise VispeechError(f"{path}: no face found in any of its {len(rows)} frames")
    width = len(names) + len(HEAD_CHANNELS)
    values = np.array([r if r is not None else np.full(width, np.nan) for r in rows])
    landmarks = np.array([p if p is not None else np.full((len(LANDMARKS), 3), np.nan) for p in points])
    return FaceTrack(values, (*names, *HEAD_CHANNELS), landmarks, fps, size)


def _head_pose(matrix: np.ndarray) -> list[float]:
    """Yaw, pitch, roll (degrees) and x, y, z (the matrix's units, centimetres) of MediaPipe's
    facial transformation matrix."""
    r = matrix[:3, :3]
    yaw = np.degrees(np.arctan2(r[0, 2], r[2, 2]))
    pitch = np.degrees(np.arcsin(np.clip(-r[1, 2], -1.0, 1.0)))
    roll = np.degrees(np.arctan2(r[1, 0], r[1, 1]))
    return [float(yaw), float(pitch), float(roll), *map(float, matrix[:3, 3])]
