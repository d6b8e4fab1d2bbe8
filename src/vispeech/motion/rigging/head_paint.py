"""Vertex colours for a head with flat materials, painted from its own geometry and morph targets.

A head like the ICT head comes with one flat colour per material and no textures: lips the
colour of the cheeks, a mouth lit as brightly at the throat as at the lips, no brows. Its
geometry says where the features are (:func:`~vispeech.motion.rigging.face.find_face`: the
mouth hole, the eye holes, ``ED`` the distance between the eye holes' outer corners, ``W`` an
eye hole's width), so :func:`paint_skin` and :func:`paint_mouth` paint ``COLOR_0`` (which
multiplies each material's base colour):

- **the skin**:
  - lips: within a band of the mouth hole's rim, as deep as the vermilion of an adult's lips
    (upper 0.09 ED, lower 0.11 ED at the middle, seen from the front), narrowing towards
    the corners (``(1 − u²)^0.4``, ``u`` from −1 to 1 between them), tinted to a lip red that
    fades into the skin over the band's outer 45 % (:func:`lip_weights`); inside the lips,
    within 0.04 ED of the rim, the wet inner lip darkens into the mouth (to 0.35 at the rim);
  - brows: an arch above each eye from 0.1 W inside its inner corner to 0.2 W beyond its outer
    one, its centre line 0.55 W above the eye's centre rising by 0.12 W to a peak two thirds of
    the way out, 0.4 W thick at the inner end and 0.16 W at the tail, a dark brown;
  - lash line: the upper rim of each eye hole, within 0.06 W of it, nearly black;
  - complexion: the cheeks (0.3 ED around a point 0.45 ED below and 0.05 ED outside each eye's
    centre), the nose's tip (0.12 ED around the skin's foremost point above the mouth) and the
    ears (the skin beyond 0.85 of its half-width at eye height) flushed red, the skin under
    each eye a little darker, and the whole skin mottled by ±3 % over a few centimetres, so it
    is not one flat colour;
- **the mouth** (the primitives named for the tongue, gums or teeth, and the cavity's walls,
  :mod:`~vispeech.motion.rigging.mouth`): darker with depth behind the lips' front, as the
  little light that gets past the lips falls off (:func:`mouth_light`: ``0.02 + 0.98·exp(−d /
  12 mm)`` of the base colour at ``d`` behind them: the front teeth, about 1 cm back, at 0.4,
  the back of the tongue at under 0.1); the tongue
  (:func:`~vispeech.motion.rigging.tongue.find_tongue`) a tongue's red, the gums and the walls a
  mucosa's pink-red (:data:`TONGUE`, :data:`MUCOSA`). The same share is written as the
  vertices' ``_OCCLUSION``, with which the web viewer, which draws no shadows, dims the
  highlights inside the mouth too (vertex colours dim only the diffuse light).
"""

from __future__ import annotations

import numpy as np

from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.face import Face
from vispeech.motion.rigging.glb import Primitive

LIPS = np.array([0.9, 0.63, 0.63])
LIP_DEPTH = (0.09, 0.11)  # upper, lower: × ED
LIP_FADE = 0.55  # share of the band's depth where the lip colour starts to fade into the skin
INNER_LIP = (0.04, 0.35)  # × ED within the rim, the light left at the rim
BROWS = np.array([0.3, 0.22, 0.18])
LASHES = np.array([0.15, 0.12, 0.12])
LASH_WIDTH = 0.06  # × W
FLUSH = np.array([1.0, 0.84, 0.82])
UNDER_EYE = np.array([0.9, 0.86, 0.9])
MOTTLE = 0.03
TONGUE = np.array([0.82, 0.62, 0.66])
"""Multiplies the mouth material's base colour on the tongue."""
MUCOSA = np.array([0.95, 0.75, 0.78])
"""Multiplies the base colour of the gums and of the cavity's walls (the skin's colour on the ICT head: the
walls are tinted further to :data:`WALLS`)."""
WALLS = np.array([0.75, 0.36, 0.4])
SKIN_SHEEN = {"sheenColorFactor": [0.35, 0.14, 0.1], "sheenRoughnessFactor": 0.55}
"""``KHR_materials_sheen`` of a painted skin: a soft reddish glow at grazing angles, as light scattered under
the skin gives (flat materials look like plastic or clay without it)."""
ROOTS = np.array([0.07, 0.055, 0.045])
"""Multiplies the skin's base colour where hair covers it (the ICT head's skin colour to a dark brown)."""
MOUTH_LIGHT = (0.02, 0.012)  # the light left deep in the mouth, the metres over which it falls by e


def _mix(colours: np.ndarray, tint: np.ndarray, amount: np.ndarray) -> np.ndarray:
    return colours * (1 - amount[:, None]) + tint * amount[:, None]


def lip_weights(skin: Primitive, face: Face) -> np.ndarray:
    """How much each skin vertex is lip (0..1): the band along the mouth's rim (module docstring)."""
    from scipy.spatial import cKDTree  # scipy: the `rig` extra, imported only to prepare a head

    pos = skin.positions
    mouth = face.mouth
    distance, nearest = cKDTree(pos[mouth, :2]).query(pos[:, :2])
    left, right = pos[mouth, 0].min(), pos[mouth, 0].max()
    u = np.clip((pos[:, 0] - (left + right) / 2) / ((right - left) / 2), -1.0, 1.0)
    upper = pos[:, 1] >= pos[mouth][nearest, 1]
    depth = np.where(upper, LIP_DEPTH[0], LIP_DEPTH[1]) * face.eye_distance * np.maximum(1 - u * u, 0.0) ** 0.4
    front = pos[:, 2] > pos[mouth, 2].min() - 0.05 * face.eye_distance
    return (1 - smoothstep(distance / np.maximum(depth, 1e-9), (LIP_FADE, 1.0))) * front


def paint_skin(skin: Primitive, face: Face) -> np.ndarray:
    """``COLOR_0`` of the skin primitive: lips, brows, lash line and complexion (module docstring)."""
    from scipy.spatial import cKDTree  # scipy: the `rig` extra, imported only to prepare a head

    pos = skin.positions
    colours = _complexion(pos, face)
    colours = _mix(colours, LIPS * colours, 0.9 * lip_weights(skin, face))
    rim_distance, _ = cKDTree(pos[face.mouth]).query(pos)
    inner = (1 - smoothstep(rim_distance, (0.0, INNER_LIP[0] * face.eye_distance))) * (
        pos[:, 2] < pos[face.mouth, 2].max() + 0.02 * face.eye_distance
    )
    colours *= (1 - (1 - INNER_LIP[1]) * inner)[:, None]
    mouth_x = pos[face.mouth, 0].mean()
    for rim in face.eyes:
        colours = _brow_and_lashes(colours, pos, pos[rim], mouth_x)
    return colours


def _brow_and_lashes(colours: np.ndarray, pos: np.ndarray, eye: np.ndarray, mouth_x: float) -> np.ndarray:
    """``colours`` with the brow above the eye whose rim is at ``eye`` and its lash line painted."""
    centre = eye.mean(axis=0)
    medial = np.sign(mouth_x - centre[0])  # towards the nose
    inner_x, outer_x = eye[np.argmax(medial * eye[:, 0]), 0], eye[np.argmin(medial * eye[:, 0]), 0]
    w = abs(outer_x - inner_x)
    start, end = inner_x + medial * 0.1 * w, outer_x - medial * 0.2 * w
    t = (pos[:, 0] - start) / (end - start)
    along = (t >= 0) & (t <= 1)
    tc = np.clip(t, 0.0, 1.0)
    line = (
        centre[1]
        + 0.55 * w
        + 0.12 * w * np.sin(np.pi * np.minimum(tc / 0.67, 1.0) / 2) * (1 - 0.5 * np.clip((tc - 0.67) / 0.33, 0.0, 1.0))
    )
    thick = (0.4 - 0.24 * tc) * w
    off = np.abs(pos[:, 1] - line) / (thick / 2)
    ends = smoothstep(tc, (0.0, 0.08)) * (1 - smoothstep(tc, (0.9, 1.0)))
    brow = along * (1 - smoothstep(off, (0.6, 1.0))) * ends * (pos[:, 2] > centre[2] - 0.3 * w)
    colours = _mix(colours, BROWS, 0.85 * brow)
    lid = eye[eye[:, 1] > centre[1]]
    from scipy.spatial import cKDTree  # scipy: the `rig` extra, imported only to prepare a head

    lash_distance, _ = cKDTree(lid).query(pos)
    return _mix(colours, LASHES, 1 - smoothstep(lash_distance, (0.0, LASH_WIDTH * w)))


def _complexion(pos: np.ndarray, face: Face) -> np.ndarray:
    """Per-vertex multipliers of the skin's colour: flushed cheeks, nose and ears, shadowed under-eyes, mottling."""
    ed = face.eye_distance
    colours = np.ones((len(pos), 3))
    mouth = pos[face.mouth]
    eyes = [pos[rim].mean(axis=0) for rim in face.eyes]

    def blob(centre: np.ndarray, radius: float) -> np.ndarray:
        return 1 - smoothstep(np.linalg.norm(pos - centre, axis=1) / radius, (0.2, 1.0))

    for eye in eyes:
        outward = np.sign(eye[0] - mouth[:, 0].mean())
        cheek = eye + np.array([outward * 0.05 * ed, -0.45 * ed, 0.0])
        cheek[2] = pos[np.argmin(np.linalg.norm(pos[:, :2] - cheek[:2], axis=1)), 2]
        colours = _mix(colours, FLUSH, 0.6 * blob(cheek, 0.3 * ed))
        under = eye + np.array([0.0, -0.12 * ed, 0.0])
        colours = _mix(colours, UNDER_EYE, 0.5 * blob(under, 0.12 * ed))
    above = (pos[:, 1] > mouth[:, 1].max()) & (pos[:, 1] < np.mean([e[1] for e in eyes]))
    if above.any():
        nose = pos[above][np.argmax(pos[above, 2])]
        colours = _mix(colours, FLUSH, 0.5 * blob(nose, 0.12 * ed))
    centre_x = mouth[:, 0].mean()
    half = np.abs(pos[:, 0] - centre_x).max()
    ear_height = np.abs(pos[:, 1] - np.mean([e[1] for e in eyes])) < 0.5 * ed
    ears = smoothstep(np.abs(pos[:, 0] - centre_x) / half, (0.85, 0.95)) * ear_height
    colours = _mix(colours, FLUSH, 0.6 * ears)
    k = 2 * np.pi / (0.6 * ed)
    mottle = (
        np.sin(k * pos[:, 0] + 1.3) * np.sin(0.8 * k * pos[:, 1] + 0.4)
        + np.sin(1.7 * k * pos[:, 1] + 2.1) * np.sin(1.3 * k * pos[:, 2] + 0.7)
    ) / 2
    return colours * (1 + MOTTLE * mottle)[:, None]


def mouth_front(skin: Primitive, face: Face | None, parts: list[Primitive]) -> float | None:
    """The z from which the mouth's depth counts: the lips' front (the foremost skin vertex that is more
    lip than skin, :func:`lip_weights`), else the front of the mouth's ``parts``; None without either."""
    if face is not None:
        return float(skin.positions[lip_weights(skin, face) > 0.5, 2].max())
    return max((float(p.positions[:, 2].max()) for p in parts), default=None)


def mouth_light(positions: np.ndarray, front: float) -> np.ndarray:
    """The share of the light that reaches each vertex at ``positions`` (vertices × 3) inside a mouth,
    ``d`` behind ``front`` (:func:`mouth_front`): ``0.02 + 0.98·exp(−d / 12 mm)``."""
    depth = np.maximum(front - positions[:, 2], 0.0)
    return MOUTH_LIGHT[0] + (1 - MOUTH_LIGHT[0]) * np.exp(-depth / MOUTH_LIGHT[1])


def paint_mouth(
    positions: np.ndarray, front: float, tongue: np.ndarray | None = None, tint: np.ndarray = MUCOSA
) -> np.ndarray:
    """``COLOR_0`` of vertices inside the mouth at ``positions`` (vertices × 3): :func:`mouth_light`
    behind ``front``, tinted by ``tint``; ``tongue`` (per-vertex weights 0..1) tints the tongue."""
    light = mouth_light(positions, front)
    colours = light[:, None] * tint
    if tongue is not None:
        colours = _mix(colours, light[:, None] * TONGUE, tongue)
    return colours
