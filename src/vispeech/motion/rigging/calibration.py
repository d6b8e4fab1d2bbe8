"""Amplitude calibration by geometry: from model space (tracker scores) to one head's weights.

The networks learn the scale of the tracker that labelled their corpus (MediaPipe scores on
GRID), and a head's morph targets open its mouth by their own amounts: the same jawOpen opens
two heads differently. The corpus has what settles it: per frame, the tracked scores and the
speaker's real inner-lip gap and mouth width over the eye-corner distance (MediaPipe landmarks
13-14, 61-291, 33-263; :func:`vispeech.corpus.articulation.articulatory_parameters`). A head's
morph targets give its own gap and width over its eye-corner distance, linear in the weights
(:class:`HeadGeometry`). :func:`fit_calibration` finds gains for the channels that shape the
lips (:data:`GAIN_GROUPS`: Left and Right share one, and jawOpen and mouthClose share one, so
that lips ARKit closes stay closed) in two steps: the lip-shaping gains make the head's change
of mouth width follow the human's (least squares, pulled towards 1 where the frames say
little), then the jaw's gain makes the head's inner-lip gap over the frames where the human's
lips are apart have the human's median and 90th percentile. :class:`Calibration` applies the
gains to a track (values × gain, clipped to [0, 1]) and is saved as JSON.

Head landmarks are found from the morph targets themselves: the outer eye corners are the
lateral ends of what ``eyeBlinkLeft``/``eyeBlinkRight`` move, the mouth corners the vertices
``mouthSmileLeft``/``Right`` move furthest, and on the midline the upper lip's lowest and the
lower lip's highest vertex, told apart by how far ``jawOpen`` moves them. Heads follow glTF's
axes: +Y up, the face looking along +Z.

Output scales (:func:`load_scale`): ``tracker`` (no calibration: the models' own scale, for
evaluation), ``arkit`` (the shipped calibration for the ICT-FaceKit head, whose 51 expression
shapes are modelled on ARKit's: what iPhone Live Link and MetaHuman rigs expect, see
docs/calibration.md) or a calibration file (``vispeech rig calibrate HEAD.glb``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import cache
from importlib import resources

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, read_text
from vispeech.motion.track import Track

CALIBRATION_FORMAT = "vispeech-calibration"
SCALES = ("tracker", "arkit")
"""Named output scales; anything else given as a scale is a calibration file's path."""

CLOSED_GAP = 0.02
"""Human inner-lip gap over eye distance at or below which the fit counts a frame's lips as closed."""
MAX_GAIN = 4.0
GAIN_GROUPS: dict[str, tuple[str, ...]] = {
    "jaw": ("jawOpen", "mouthClose"),  # one gain: mouthClose = jawOpen still closes the lips
    "funnel": ("mouthFunnel",),
    "pucker": ("mouthPucker",),
    "smile": ("mouthSmileLeft", "mouthSmileRight"),
    "stretch": ("mouthStretchLeft", "mouthStretchRight"),
}
"""The channels that get a gain, and share it: those that open, round and spread the lips.
Every other channel (presses, rolls, shrugs, the lips' raisers) keeps its value."""
_PRIOR = 0.3  # pull towards gain 1, per frame: the fit moves a gain only where the frames say so
_MIDLINE = 0.015  # vertices within this many eye distances of the face's midline


@dataclass(frozen=True)
class HeadGeometry:
    """A head's inner-lip gap and mouth width, in eye-corner distances, as linear functions of
    its ARKit weights: ``gap = gap0 + Σ_c w_c · gap_per[c]`` (and the same for width)."""

    gap0: float
    width0: float
    gap_per: dict[str, float]
    width_per: dict[str, float]
    eye_distance: float
    """The eye-corner distance in the model's units (metres for glTF)."""
    landmarks: dict[str, int] = field(default_factory=dict)
    """The vertices measured, by name (``upper_lip``, ``lower_lip``, ``mouth_left``,
    ``mouth_right``, ``eye_left``, ``eye_right``), indices into the skin primitive's vertices."""

    @classmethod
    def from_glb(cls, path: str | os.PathLike) -> HeadGeometry:
        """Measure a GLB head (see the module docstring); :class:`VispeechError` when its morph
        targets lack what the landmarks are found by."""
        from vispeech.motion.rigging.glb import read_morph_mesh

        mesh = read_morph_mesh(path)
        needed = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight")
        missing = [name for name in needed if name not in mesh.targets]
        if missing:
            raise VispeechError(
                f"{path}: the head lacks the morph targets {', '.join(missing)} that find its landmarks"
            )
        base, targets = mesh.positions, mesh.targets
        eye_left, eye_right = (
            _outer_eye_corner(base, targets[f"eyeBlink{side}"], sign) for side, sign in (("Left", 1.0), ("Right", -1.0))
        )
        eye_distance = float(np.linalg.norm(base[eye_left] - base[eye_right]))
        centre = (base[eye_left, 0] + base[eye_right, 0]) / 2
        corner_left, corner_right = (
            int(np.argmax(np.linalg.norm(targets[f"mouthSmile{side}"], axis=1))) for side in ("Left", "Right")
        )
        upper, lower = _inner_lips(base, targets["jawOpen"], centre, eye_distance, base[[corner_left, corner_right], 1])
        gap_per = {name: float(d[upper, 1] - d[lower, 1]) / eye_distance for name, d in targets.items()}
        width_per = {name: float(d[corner_left, 0] - d[corner_right, 0]) / eye_distance for name, d in targets.items()}
        landmarks = {
            "upper_lip": upper,
            "lower_lip": lower,
            "mouth_left": corner_left,
            "mouth_right": corner_right,
            "eye_left": eye_left,
            "eye_right": eye_right,
        }
        return cls(
            float(base[upper, 1] - base[lower, 1]) / eye_distance,
            float(base[corner_left, 0] - base[corner_right, 0]) / eye_distance,
            {k: v for k, v in gap_per.items() if v},
            {k: v for k, v in width_per.items() if v},
            eye_distance,
            landmarks,
        )

    def gap(self, track: Track) -> np.ndarray:
        """Per frame, the head's inner-lip gap over its eye distance at ``track``'s weights
        (at least 0: lips pressed together do not make a negative gap)."""
        return np.maximum(self._linear(track, self.gap0, self.gap_per), 0.0)

    def width(self, track: Track) -> np.ndarray:
        """Per frame, the head's mouth width (corner to corner) over its eye distance."""
        return self._linear(track, self.width0, self.width_per)

    @staticmethod
    def _linear(track: Track, rest: float, per: dict[str, float]) -> np.ndarray:
        out = np.full(track.n_frames, rest)
        for name, slope in per.items():
            if name in track.channels:
                out += slope * np.asarray(track[name], dtype=float)
        return out


@dataclass(frozen=True)
class Calibration:
    """Per-channel gains from model space to a head's weights; channels not named keep theirs."""

    gains: dict[str, float]
    head: str = ""
    """What it was fitted for (a file name; ``ICT-FaceKit`` for the shipped ``arkit`` scale)."""
    fit: dict = field(default_factory=dict)
    """How well: the fit's figures (medians and 90th percentiles of the gaps, frames used)."""

    def apply(self, track: Track) -> Track:
        """``track`` in the head's weights: each calibrated channel times its gain, clipped to [0, 1]."""
        values = np.array(track.values, dtype=float, copy=True)
        calibrated = [(track.channels.index(name), gain) for name, gain in self.gains.items() if name in track.channels]
        if calibrated:
            columns, gains = zip(*calibrated)
            values[:, list(columns)] = np.clip(values[:, list(columns)] * np.array(gains), 0.0, 1.0)
        return Track(values, track.channels, track.fps, track.start_time)

    def to_dict(self) -> dict:
        return {
            "format": CALIBRATION_FORMAT,
            "version": 1,
            "head": self.head,
            "gains": {k: round(v, 6) for k, v in self.gains.items()},
            "fit": self.fit,
        }

    def save(self, path: str | os.PathLike) -> None:
        """Write the calibration as JSON (atomically)."""
        with atomic_output_file(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")

    @classmethod
    def from_dict(cls, data: object, where: str = "calibration") -> Calibration:
        if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
            raise VispeechError(f"{where} is not a {CALIBRATION_FORMAT} file")
        gains = data.get("gains")
        if not isinstance(gains, dict) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= MAX_GAIN for v in gains.values()
        ):
            raise VispeechError(f"{where}: 'gains' must map channel names to numbers in [0, {MAX_GAIN:g}]")
        return cls({str(k): float(v) for k, v in gains.items()}, str(data.get("head", "")), dict(data.get("fit", {})))

    @classmethod
    def load(cls, path: str | os.PathLike) -> Calibration:
        """Read a calibration written by :meth:`save`; :class:`VispeechError` on a bad file."""
        text = read_text(path, "calibration file")
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise VispeechError(f"{path} is not JSON: {exc.msg} (line {exc.lineno})") from None
        return cls.from_dict(data, str(path))


FRAMES_FILE = "grid_s1_mouth_frames.npz"
"""The shipped sample of human frames (in ``vispeech/motion/rigging/data``): 5,000 tracked frames of
grid_s1's training split (GRID corpus, CC BY 4.0), their lip-channel scores, inner-lip gap and
mouth width; written by ``vispeech rig mouth-frames`` (docs/calibration.md)."""


def save_mouth_frames(
    path: str | os.PathLike,
    scores: Track,
    gap: np.ndarray,
    width: np.ndarray,
    *,
    frames: int = 5000,
    seed: int = 0,
    source: str = "",
) -> None:
    """Write a random sample of ``frames`` frames (the lip channels' scores, gap, width) as .npz."""
    rng = np.random.default_rng(seed)
    keep = np.sort(rng.choice(scores.n_frames, size=min(frames, scores.n_frames), replace=False))
    channels = [c for c in scores.channels if c.startswith(("jaw", "mouth"))]
    with atomic_output_file(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(
            f,
            channels=np.array(channels),
            source=np.array(source),
            fps=np.array(scores.fps),
            scores=np.column_stack([scores[c] for c in channels])[keep].astype(np.float32),
            gap=np.asarray(gap, dtype=np.float32)[keep],
            width=np.asarray(width, dtype=np.float32)[keep],
        )


def load_mouth_frames(path: str | os.PathLike | None = None) -> tuple[Track, np.ndarray, np.ndarray, str]:
    """``(scores, gap, width, source)`` from :func:`save_mouth_frames`'s file (default: the shipped one)."""
    try:
        if path is None:
            with resources.files("vispeech.motion.rigging").joinpath(f"data/{FRAMES_FILE}").open("rb") as f:
                data = dict(np.load(f))
        else:
            with np.load(path) as loaded:
                data = dict(loaded)
        scores = Track(data["scores"].astype(np.float64), tuple(str(c) for c in data["channels"]), float(data["fps"]))
        return scores, data["gap"].astype(np.float64), data["width"].astype(np.float64), str(data["source"])
    except (OSError, KeyError, ValueError) as exc:
        raise VispeechError(f"cannot read mouth frames {path or FRAMES_FILE}: {exc}") from None


def load_scale(scale: str | os.PathLike | None) -> Calibration | None:
    """The calibration an output scale names: ``None`` for ``tracker`` (or ``None``), the shipped
    one for ``arkit``, else the calibration file at that path."""
    if scale is None or str(scale) == "tracker":
        return None
    if str(scale) == "arkit":
        return _arkit()
    if not os.path.isfile(scale):
        raise VispeechError(
            f"unknown output scale {str(scale)!r}: use tracker, arkit or a calibration file "
            "(vispeech rig calibrate HEAD.glb)"
        )
    return Calibration.load(scale)


@cache
def _arkit() -> Calibration:
    """The shipped ``arkit`` calibration, read once (every output of a batch or a server uses it)."""
    shipped = resources.files("vispeech.motion.rigging").joinpath("data/arkit.calibration.json")
    text = shipped.read_text(encoding="utf-8")
    return Calibration.from_dict(json.loads(text), "the shipped arkit calibration")


def fit_calibration(
    head: HeadGeometry, scores: Track, gap: np.ndarray, width: np.ndarray, name: str = ""
) -> Calibration:
    """Gains that make ``head``'s gap and width follow a human's.

    ``scores`` are tracked frames in model space (a corpus's tracks, concatenated), ``gap`` and
    ``width`` the same frames' inner-lip gap and mouth width over the eye-corner distance.
    The steps are the module docstring's; gains lie in [0, :data:`MAX_GAIN`]. The width is
    fitted as a change from each face's rest (the human's rest from a linear fit of width on
    the scores), since faces differ in how wide their mouths are. ``fit`` of the result holds
    :func:`compare_gaps` on the frames. Raises :class:`VispeechError` for frames that do not
    match, lack open or closed lips, or share no lip channel with the head.
    """
    from scipy.optimize import least_squares, minimize_scalar

    gap, width = np.asarray(gap, dtype=float), np.asarray(width, dtype=float)
    if not (len(gap) == len(width) == scores.n_frames) or scores.n_frames < 10:
        raise VispeechError("calibration needs at least 10 frames of scores, gaps and widths of equal length")
    keep = np.isfinite(gap) & np.isfinite(width) & np.all(np.isfinite(scores.values), axis=1)
    fitted = Track(np.asarray(scores.values, dtype=float)[keep], scores.channels, scores.fps)
    gap, width = gap[keep], width[keep]
    open_ = gap > CLOSED_GAP
    if open_.sum() < 10 or (~open_).sum() < 1:
        raise VispeechError("calibration needs frames with the lips apart and frames with them closed")
    groups = {g: [c for c in members if c in fitted.channels] for g, members in GAIN_GROUPS.items()}
    groups = {
        g: members
        for g, members in groups.items()
        if any(head.gap_per.get(c) or head.width_per.get(c) for c in members)
    }
    if "jaw" not in groups:
        raise VispeechError("calibration needs jawOpen in the scores and on the head")
    x = {c: np.asarray(fitted[c], dtype=float) for c in fitted.channels}

    # 1. the lip-shaping groups: the head's change of mouth width follows the human's
    shaping = [g for g in groups if g != "jaw"]
    columns = np.column_stack(
        [sum(head.width_per.get(c, 0.0) * x[c] for c in groups[g]) for g in shaping] or [np.zeros(len(gap))]
    )
    fixed = sum(head.width_per.get(c, 0.0) * x[c] for c in x if not any(c in groups[g] for g in shaping))
    design = np.column_stack([np.ones(len(gap))] + [x[c] for c in sorted(x)])
    target = width - np.linalg.lstsq(design, width, rcond=None)[0][0]  # the human's change from rest
    scale, prior = np.std(target) or 1.0, np.sqrt(_PRIOR * len(gap))
    k = np.ones(len(shaping))
    if shaping:
        k = least_squares(
            lambda k: np.concatenate([(fixed + columns @ k - target) / scale, prior * (k - 1.0)]),
            k,
            bounds=(0.0, MAX_GAIN),
        ).x
    gains = {c: float(v) for g, v in zip(shaping, k) for c in groups[g]}

    # 2. the jaw: the head's gap over open frames has the human's median and 90th percentile
    def mismatch(jaw: float) -> float:
        head_gap = head.gap(Calibration({**gains, **{c: jaw for c in groups["jaw"]}}).apply(fitted))[open_]
        return sum(
            float(np.log(max(np.percentile(head_gap, q), 1e-9) / np.percentile(gap[open_], q))) ** 2 for q in (50, 90)
        )

    jaw = float(minimize_scalar(mismatch, bounds=(0.0, MAX_GAIN), method="bounded", options={"xatol": 1e-3}).x)
    gains.update({c: jaw for c in groups["jaw"]})
    gains = {c: round(v, 4) for c, v in gains.items()}
    calibrated = Calibration(gains, name).apply(fitted)
    fit = compare_gaps(head, calibrated, gap, raw=fitted)
    for label, t in (("calibrated", calibrated), ("raw", fitted)):  # how the widths' changes go together
        fit[label]["width_r"] = round(float(np.corrcoef(head.width(t), width)[0, 1]), 4)
        fit[label]["width_change_ratio"] = round(float(np.std(head.width(t)) / np.std(width)), 4)
    return Calibration(gains, name, fit)


def compare_gaps(head: HeadGeometry, track: Track, human_gap: np.ndarray, *, raw: Track | None = None) -> dict:
    """The head's gap on ``track`` against a human's on the same frames, over speech-like frames
    (human lips apart): medians, 90th percentiles and their ratios; with ``raw`` the same for
    the uncalibrated track."""
    human_gap = np.asarray(human_gap, dtype=float)
    open_ = human_gap > CLOSED_GAP
    closed = ~open_
    out: dict = {"frames": int(len(human_gap)), "open_frames": int(open_.sum())}
    for label, t in (("calibrated", track), ("raw", raw)):
        if t is None:
            continue
        g = head.gap(t)
        out[label] = {
            "median_ratio": round(float(np.median(g[open_]) / np.median(human_gap[open_])), 4),
            "p90_ratio": round(float(np.percentile(g[open_], 90) / np.percentile(human_gap[open_], 90)), 4),
            "closed_median_gap": round(float(np.median(g[closed])) if closed.any() else 0.0, 4),
        }
    out["human"] = {
        "median": round(float(np.median(human_gap[open_])), 4),
        "p90": round(float(np.percentile(human_gap[open_], 90)), 4),
    }
    return out


def _outer_eye_corner(base: np.ndarray, blink: np.ndarray, sign: float) -> int:
    """The vertex at the lateral end (towards ``sign`` · x) of the skin a blink moves."""
    reach = np.linalg.norm(blink, axis=1)
    moved = np.flatnonzero(reach > 0.1 * reach.max())
    return int(moved[np.argmax(sign * base[moved, 0])])


def _inner_lips(
    base: np.ndarray, jaw: np.ndarray, centre: float, eye_distance: float, corner_heights: np.ndarray
) -> tuple[int, int]:
    """The upper lip's lowest and the lower lip's highest vertex on the midline near the mouth."""
    mouth = float(np.mean(corner_heights))
    near = np.flatnonzero(
        (np.abs(base[:, 0] - centre) < _MIDLINE * eye_distance) & (np.abs(base[:, 1] - mouth) < 0.3 * eye_distance)
    )
    if len(near) < 2:
        raise VispeechError("found no midline vertices at the mouth: is the head facing +Z with +Y up?")
    drop = -jaw[near, 1]
    lower = drop > 0.5 * drop.max()
    if lower.all() or not lower.any():
        raise VispeechError("jawOpen does not separate the lips on the midline")
    upper_ids, lower_ids = near[~lower], near[lower]
    return int(upper_ids[np.argmin(base[upper_ids, 1])]), int(lower_ids[np.argmax(base[lower_ids, 1])])
