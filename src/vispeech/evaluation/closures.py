"""Lip closures: where the tracked lips close, where a model's do, and how well they agree.

Tracked lips are closed where the inner-lip gap (MediaPipe landmarks 13 and 14) divided by
the eye-corner distance (33 to 263), both measured in video pixels, is at most
:data:`TRACKED_CLOSED`. A model's lips are closed where ``jawOpen − mouthClose`` (for
articulatory tracks: ``lip_aperture``) is at most :data:`MODEL_CLOSED` of its maximum over
the utterance. :func:`count_closures` compares both on the bilabial stops and nasals
(/p b m/) and over the speech frames.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from vispeech.alignment.phones import PhoneSequence, first_frame
from vispeech.corpus.articulation import FRAME_SIZE, lip_gap
from vispeech.errors import VispeechError
from vispeech.motion.track import Track
from vispeech.phonetics.features import FEATURE_NAMES, phone_features
from vispeech.phonetics.inventory import is_silence

TRACKED_CLOSED = 0.02
"""Inner-lip gap over eye-corner distance at or below which tracked lips count as closed."""

MODEL_CLOSED = 0.10
"""Fraction of its utterance maximum at or below which a model's lip opening counts as closed."""

BILABIAL_RATE_TARGET = 90.0
"""Percentage of tracked /p b m/ closures a model should close on too."""

CLOSED_SHARE_TOLERANCE = 5.0
"""Percentage points by which a model's share of closed speech frames may differ from the tracked one."""

_BILABIAL = FEATURE_NAMES.index("bilabial")


def tracked_closed(landmarks: dict[str, np.ndarray], frame_size: tuple[int, int] = FRAME_SIZE) -> np.ndarray:
    """Boolean mask of the frames where the tracked lips are closed (see
    :func:`vispeech.corpus.articulation.lip_gap`)."""
    return lip_gap(landmarks, frame_size) <= TRACKED_CLOSED


def lip_opening(track: Track) -> np.ndarray | None:
    """A model's lip opening per frame: ``jawOpen − mouthClose``, or the ``lip_aperture``
    channel of an articulatory track; ``None`` when the track has neither."""
    if "jawOpen" in track.channels:
        return track["jawOpen"] - track.get("mouthClose")
    if "lip_aperture" in track.channels:
        return track["lip_aperture"].copy()
    return None


def model_closed(track: Track, fraction: float = MODEL_CLOSED) -> np.ndarray:
    """Boolean mask of the frames where a track's lips are closed: :func:`lip_opening` at
    most ``fraction`` of its maximum over the track (all frames if it never exceeds 0)."""
    opening = lip_opening(track)
    if opening is None:
        raise VispeechError("the track has neither jawOpen nor lip_aperture: cannot tell lip closures")
    peak = opening.max(initial=0.0)
    if peak <= 0:
        return np.ones(track.n_frames, dtype=bool)
    return opening <= fraction * peak


def is_bilabial(symbol: str, language: str) -> bool:
    """Whether a phone is a bilabial stop or nasal (ARPAbet P, B, M; Swedish p, b, m)."""
    if is_silence(symbol):
        return False
    try:
        return bool(phone_features(symbol, language)[_BILABIAL] > 0)
    except VispeechError:
        return False


PHONE_CLASSES = ("vowel", "bilabial", "labiodental", "other consonant", "silence")
"""The classes :func:`phone_class` puts phones in, for errors per class."""


def phone_class(symbol: str, language: str) -> str:
    """One of :data:`PHONE_CLASSES`: what a phone does to the lips."""
    if is_silence(symbol):
        return "silence"
    try:
        features = phone_features(symbol, language)
    except VispeechError:
        return "other consonant"
    for name in ("vowel", "bilabial", "labiodental"):
        if features[FEATURE_NAMES.index(name)] > 0:
            return name
    return "other consonant"


def frame_classes(phones: PhoneSequence, fps: float, n_frames: int, start_time: float = 0.0) -> np.ndarray:
    """Per frame, the index in :data:`PHONE_CLASSES` of the phone it falls in (silence outside them)."""
    out = np.full(n_frames, PHONE_CLASSES.index("silence"))
    times = start_time + np.arange(n_frames) / fps
    for phone in phones:
        inside = (times >= phone.start) & (times < phone.end)
        out[inside] = PHONE_CLASSES.index(phone_class(phone.symbol, phones.language))
    return out


def phone_frames(
    start: float, end: float, fps: float, n_frames: int, start_time: float = 0.0, pad: int = 1
) -> np.ndarray:
    """Indices of the frames a phone ``[start, end)`` (seconds) covers, widened by ``pad`` frames
    on each side. A phone shorter than a frame covers the frame nearest its middle."""
    first = first_frame(start - start_time, fps)
    last = first_frame(end - start_time, fps) - 1
    if last < first:
        first = last = int(round(((start + end) / 2 - start_time) * fps))
    return np.arange(max(first - pad, 0), min(last + pad, n_frames - 1) + 1)


@dataclass
class ClosureCounts:
    """Closure agreement counts; add them up over utterances with ``+``.

    ``bilabials``: /p b m/ phones scored; ``tracked_closures``: those on which the tracked
    lips close (in a frame of the phone ± 1 frame); ``model_closures``: those of the tracked
    closures on which the model closes too. ``speech_frames``: tracked frames in the speech
    span; ``tracked_closed_frames`` and ``model_closed_frames``: those with closed lips.
    ``onset_ms`` and ``release_ms``: for each closure both make, milliseconds from the start (end)
    of the tracked lips' closed run over the phone to the start (end) of the model's (positive:
    the model is late).
    """

    bilabials: int = 0
    tracked_closures: int = 0
    model_closures: int = 0
    speech_frames: int = 0
    tracked_closed_frames: int = 0
    model_closed_frames: int = 0
    onset_ms: tuple[float, ...] = ()
    release_ms: tuple[float, ...] = ()

    def __add__(self, other: ClosureCounts) -> ClosureCounts:
        return ClosureCounts(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    @property
    def bilabial_rate(self) -> float:
        """Percentage of tracked /p b m/ closures the model closes on too (NaN with none)."""
        return 100.0 * self.model_closures / self.tracked_closures if self.tracked_closures else float("nan")

    @property
    def tracked_closed_share(self) -> float:
        """Percentage of speech frames with tracked lips closed."""
        return 100.0 * self.tracked_closed_frames / self.speech_frames if self.speech_frames else float("nan")

    @property
    def model_closed_share(self) -> float:
        """Percentage of speech frames with the model's lips closed."""
        return 100.0 * self.model_closed_frames / self.speech_frames if self.speech_frames else float("nan")

    def timing(self) -> dict[str, float]:
        """Median and mean absolute closure onset and release offsets (ms; NaN with none)."""
        out = {}
        for name, values in (("onset", self.onset_ms), ("release", self.release_ms)):
            v = np.asarray(values, dtype=float)
            out[f"{name}_median_ms"] = float(np.median(v)) if len(v) else float("nan")
            out[f"{name}_mean_abs_ms"] = float(np.abs(v).mean()) if len(v) else float("nan")
        return out

    @property
    def passed(self) -> bool:
        """Bilabial rate ≥ :data:`BILABIAL_RATE_TARGET` and closed shares within
        :data:`CLOSED_SHARE_TOLERANCE` points of each other."""
        return (
            self.bilabial_rate >= BILABIAL_RATE_TARGET
            and abs(self.model_closed_share - self.tracked_closed_share) <= CLOSED_SHARE_TOLERANCE
        )


def count_closures(
    phones: PhoneSequence,
    fps: float,
    tracked: np.ndarray,
    model: np.ndarray,
    speech: np.ndarray,
    start_time: float = 0.0,
) -> ClosureCounts:
    """Compare the closed-lip masks ``tracked`` and ``model`` (per frame, at ``fps``, frame k at
    ``start_time + k / fps`` seconds) on one utterance.

    ``speech`` masks the frames that count: the speech span, without untracked frames. A
    /p b m/ phone is scored when one of its frames (± 1) is in ``speech``.
    """
    tracked, model, speech = (np.asarray(a, dtype=bool) for a in (tracked, model, speech))
    if not (tracked.shape == model.shape == speech.shape and tracked.ndim == 1):
        raise VispeechError(f"closure masks differ in length: {tracked.shape}, {model.shape}, {speech.shape}")
    counts = ClosureCounts(
        speech_frames=int(speech.sum()),
        tracked_closed_frames=int((tracked & speech).sum()),
        model_closed_frames=int((model & speech).sum()),
    )
    for phone in phones:
        if not is_bilabial(phone.symbol, phones.language):
            continue
        frames = phone_frames(phone.start, phone.end, fps, len(speech), start_time)
        frames = frames[speech[frames]]
        if not len(frames):
            continue
        counts.bilabials += 1
        if tracked[frames].any():
            counts.tracked_closures += 1
            counts.model_closures += int(model[frames].any())
            if model[frames].any():
                (t0, t1), (m0, m1) = (_run(mask, frames[mask[frames]][0]) for mask in (tracked, model))
                counts.onset_ms += ((m0 - t0) * 1000.0 / fps,)
                counts.release_ms += ((m1 - t1) * 1000.0 / fps,)
    return counts


def _run(mask: np.ndarray, k: int) -> tuple[int, int]:
    """First and last frame of the run of True in ``mask`` that holds frame ``k``."""
    first, last = k, k
    while first > 0 and mask[first - 1]:
        first -= 1
    while last < len(mask) - 1 and mask[last + 1]:
        last += 1
    return first, last
