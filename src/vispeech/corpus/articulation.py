"""Beskow-style articulatory parameters measured on tracked face landmarks.

Landmarks (MediaPipe face-mesh indices, image-normalised) are turned into pixels
(x * width, y * height, z * width), then moved into a head frame so that head motion drops
out: origin at the nose tip (1), first axis along the eye corners 33 -> 263, second axis
towards the forehead (10), third axis out of the face; lengths are divided by the eye-corner
distance. Every parameter is therefore a fraction of the distance between the outer eye
corners (about 9 cm on an adult face), whatever the head's pose and distance to the camera.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vispeech.corpus.corpus import Corpus, Utterance, recorded_track
from vispeech.errors import VispeechError
from vispeech.motion.arkit import ARTICULATORY_CHANNELS
from vispeech.motion.track import Track

FRAME_SIZE = (360, 288)
"""Width and height in pixels of the video the GRID landmarks were tracked on."""

_NEEDED = (1, 10, 33, 263, 152, 13, 14, 61, 291, 0, 17)


def lip_gap(landmarks: dict[str, np.ndarray], frame_size: tuple[int, int] = FRAME_SIZE) -> np.ndarray:
    """Per frame, the inner-lip gap (landmarks 13 to 14) over the eye-corner distance (33 to 263),
    in the image plane.

    ``landmarks`` maps ``"lm<K>"`` to ``(frames, 3)`` image-normalised coordinates; x and y
    are scaled to pixels by ``frame_size`` (width, height) and only they are used.
    """
    absent = [k for k in ("lm13", "lm14", "lm33", "lm263") if k not in landmarks]
    if absent:
        raise VispeechError(f"landmarks {', '.join(absent)} are missing")
    scale = np.array(frame_size, dtype=float)

    def distance(a: str, b: str) -> np.ndarray:
        return np.linalg.norm((np.asarray(landmarks[a])[:, :2] - np.asarray(landmarks[b])[:, :2]) * scale, axis=1)

    eyes = distance("lm33", "lm263")
    if np.any(eyes < 1e-9):
        raise VispeechError("eye corners coincide: cannot scale the lip gap")
    return distance("lm13", "lm14") / eyes


def articulatory_parameters(utterance: Utterance, frame_size: tuple[int, int] = FRAME_SIZE) -> Track:
    """Jaw opening, lip aperture, lip width and protrusion per frame, in eye-corner distances.

    ``frame_size`` is the tracked video's (width, height) in pixels. The track has the
    utterance's frame rate and start time. Raises :class:`VispeechError` if the utterance
    has no landmarks or lacks one of those listed in :data:`ARTICULATORY_CHANNELS` or the
    head-frame ones (1, 10, 33, 263).
    """
    if utterance.landmarks is None:
        raise VispeechError(f"utterance {utterance.id} has no face landmarks")
    absent = [k for k in _NEEDED if f"lm{k}" not in utterance.landmarks]
    if absent:
        raise VispeechError(f"utterance {utterance.id} lacks landmarks {', '.join(map(str, absent))}")
    width, height = frame_size
    scale = np.array([width, height, width], dtype=float)
    points = {k: np.asarray(utterance.landmarks[f"lm{k}"], dtype=float) * scale for k in _NEEDED}
    head = _head_frame(points)

    jaw = np.linalg.norm(head[152] - head[1], axis=1)
    aperture = np.linalg.norm(head[13] - head[14], axis=1)
    width_ = np.linalg.norm(head[61] - head[291], axis=1)
    protrusion = (head[0][:, 2] + head[17][:, 2]) / 2 - (head[61][:, 2] + head[291][:, 2]) / 2
    values = np.column_stack([jaw, aperture, width_, protrusion])
    track = recorded_track(utterance)
    return Track(values, ARTICULATORY_CHANNELS, track.fps, track.start_time)


LIP_LANDMARKS: tuple[int, ...] = (13, 14, 78, 308, 0, 17, 61, 291, 37, 267, 84, 314)
"""The mesh points on the lips that GRID's tracks keep: inner and outer contours and corners."""


def lip_shape(landmarks: dict[str, np.ndarray], frame_size: tuple[int, int] = FRAME_SIZE) -> np.ndarray:
    """Per frame, the :data:`LIP_LANDMARKS` in the head frame (see the module docstring), in
    eye-corner distances: frames × 12 × 3. Raises :class:`VispeechError` when one is missing."""
    needed = (1, 10, 33, 263, *LIP_LANDMARKS)
    absent = [k for k in needed if f"lm{k}" not in landmarks]
    if absent:
        raise VispeechError(f"landmarks {', '.join(map(str, absent))} are missing")
    width, height = frame_size
    scale = np.array([width, height, width], dtype=float)
    head = _head_frame({k: np.asarray(landmarks[f"lm{k}"], dtype=float) * scale for k in needed})
    return np.stack([head[k] for k in LIP_LANDMARKS], axis=1)


def _head_frame(points: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Landmarks in head coordinates (x: eye line, y: up to the forehead, z: out of the face),
    in units of the eye-corner distance, origin at the nose tip."""
    across = points[263] - points[33]
    eye_distance = np.linalg.norm(across, axis=1, keepdims=True)
    if np.any(eye_distance < 1e-9):
        raise VispeechError("eye corners coincide: cannot build a head frame")
    x_axis = across / eye_distance
    up = points[10] - (points[33] + points[263]) / 2
    up = up - np.sum(up * x_axis, axis=1, keepdims=True) * x_axis
    y_axis = up / np.linalg.norm(up, axis=1, keepdims=True)
    # Image y points down and MediaPipe z away from the camera, so x cross y points out of the face.
    z_axis = np.cross(x_axis, y_axis)
    rotation = np.stack([x_axis, y_axis, z_axis], axis=1)  # (frames, 3 axes, 3 coordinates)
    return {k: np.einsum("fij,fj->fi", rotation, p - points[1]) / eye_distance for k, p in points.items()}


def with_articulatory_tracks(corpus: Corpus) -> Corpus:
    """A copy of ``corpus`` whose utterances' tracks are their :func:`articulatory_parameters`
    (what a model with ``targets="articulatory"`` trains on)."""
    utterances = [replace(u, track=articulatory_parameters(u)) for u in corpus.utterances]
    return replace(corpus, utterances=utterances, channels=ARTICULATORY_CHANNELS)


def mouth_frames(corpus: Corpus, frame_size: tuple[int, int] = FRAME_SIZE) -> tuple[Track, np.ndarray, np.ndarray]:
    """Every tracked frame of ``corpus`` (frames where the tracker lost the face left out):
    the scores, and the speaker's inner-lip gap and mouth width over the eye-corner distance
    (``lip_aperture`` and ``lip_width`` of :func:`articulatory_parameters`), what
    :func:`vispeech.motion.rigging.calibration.fit_calibration` fits a head to."""
    scores, gaps, widths = [], [], []
    for utterance in corpus:
        track = recorded_track(utterance)
        tracked = np.ones(track.n_frames, bool) if utterance.frame_mask is None else utterance.frame_mask
        parameters = articulatory_parameters(utterance, frame_size)
        scores.append(track.values[tracked])
        gaps.append(parameters["lip_aperture"][tracked])
        widths.append(parameters["lip_width"][tracked])
    if not scores:
        raise VispeechError(f"corpus {corpus.name} has no utterances")
    return Track(np.vstack(scores), corpus.channels, corpus.fps), np.concatenate(gaps), np.concatenate(widths)
