"""Vertex colours for a head with flat materials, painted from its own geometry and morph targets.

A head like the ICT head comes with one flat colour per material and no textures: lips the
colour of the cheeks, a mouth lit as brightly at the throat as at the lips, no brows. Its
geometry says where the features are, so :func:`paint_skin` and :func:`paint_mouth` paint
``COLOR_0`` (which multiplies each material's base colour):

- **the skin** (the primitive the eyelids' ``eyeBlinkLeft`` moves furthest). Its holes are the
  mouth (the hole ``jawOpen`` moves) and the eyes (those ``eyeBlink`` moves); ``ED`` is the
  distance between the eye holes' outer corners, ``W`` an eye hole's width.
  - lips: within a band of the mouth hole's rim, as deep as the vermilion of an adult's lips
    (upper 0.09 ED, lower 0.11 ED at the middle, seen from the front), narrowing towards
    the corners (``(1 − u²)^0.4``, ``u`` from −1 to 1 between them), tinted to a lip red;
  - brows: an arch above each eye from 0.1 W inside its inner corner to 0.2 W beyond its outer
    one, its centre line 0.55 W above the eye's centre rising by 0.12 W to a peak two thirds of
    the way out, 0.4 W thick at the inner end and 0.16 W at the tail, a dark brown;
  - lash line: the upper rim of each eye hole, within 0.06 W of it, nearly black;
- **the mouth** (the primitives named for the tongue, gums or teeth): darkened with depth from
  the lips back (front 1.0, throat 0.25 of the base colour), as the little light that gets in
  the mouth falls off; the tongue (:func:`~vispeech.motion.rigging.tongue.find_tongue`) a deeper red than
  the gums.
"""

from __future__ import annotations

import numpy as np

from vispeech.errors import VispeechError
from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.glb import Primitive

LIPS = np.array([0.86, 0.58, 0.6])
LIP_DEPTH = (0.09, 0.11)  # upper, lower: × ED
BROWS = np.array([0.3, 0.22, 0.18])
LASHES = np.array([0.15, 0.12, 0.12])
LASH_WIDTH = 0.06  # × W
TONGUE = np.array([1.0, 0.85, 0.85])
MOUTH_DEPTH = (0.25, 1.0)


def _mix(colours: np.ndarray, tint: np.ndarray, amount: np.ndarray) -> np.ndarray:
    return colours * (1 - amount[:, None]) + tint * amount[:, None]


def _holes(skin: Primitive) -> list[np.ndarray]:
    """The vertex indices of each hole's rim in the skin (boundary loops but the outer one, the longest)."""
    from scipy.sparse import coo_matrix  # scipy: the `rig` extra, imported only to prepare a head
    from scipy.sparse.csgraph import connected_components

    edges = np.sort(skin.edges, axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    rim = unique[counts == 1]
    n = len(skin.positions)
    _, labels = connected_components(
        coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n)), directed=False
    )
    loops = [np.unique(rim[labels[rim[:, 0]] == k]) for k in np.unique(labels[rim[:, 0]])]
    return sorted(loops, key=len)[:-1]


def _moved(skin: Primitive, rim: np.ndarray, *names: str) -> float:
    return max(
        (float(np.linalg.norm(skin.targets[name][rim], axis=1).mean()) for name in names if name in skin.targets),
        default=0.0,
    )


def paint_skin(skin: Primitive) -> np.ndarray:
    """``COLOR_0`` of the skin primitive: lips, brows and lash line (module docstring). Raises
    :class:`VispeechError` when the skin has no mouth hole or no eye holes."""
    from scipy.spatial import cKDTree  # scipy: the `rig` extra, imported only to prepare a head

    holes = _holes(skin)
    eyes = [rim for rim in holes if _moved(skin, rim, "eyeBlinkLeft", "eyeBlinkRight") > 0]
    eyes = sorted(eyes, key=lambda rim: _moved(skin, rim, "eyeBlinkLeft", "eyeBlinkRight"))[-2:]
    mouths = [rim for rim in holes if not any(rim is e for e in eyes) and _moved(skin, rim, "jawOpen") > 0]
    if len(eyes) < 2 or not mouths:
        raise VispeechError("found no mouth hole and two eye holes in the skin to paint lips and brows by")
    mouth = max(mouths, key=lambda rim: _moved(skin, rim, "jawOpen"))
    pos = skin.positions
    colours = np.ones((len(pos), 3))
    outer = [pos[rim][np.argmax(np.abs(pos[rim, 0] - pos[mouth, 0].mean()))] for rim in eyes]
    ed = float(np.linalg.norm(outer[0] - outer[1]))
    # lips: a band along the mouth's rim
    distance, nearest = cKDTree(pos[mouth, :2]).query(pos[:, :2])
    left, right = pos[mouth, 0].min(), pos[mouth, 0].max()
    u = np.clip((pos[:, 0] - (left + right) / 2) / ((right - left) / 2), -1.0, 1.0)
    upper = pos[:, 1] >= pos[mouth][nearest, 1]
    depth = np.where(upper, LIP_DEPTH[0], LIP_DEPTH[1]) * ed * np.maximum(1 - u * u, 0.0) ** 0.4
    lips = (1 - smoothstep(distance / np.maximum(depth, 1e-9), (0.75, 1.0))) * (
        pos[:, 2] > pos[mouth, 2].min() - 0.05 * ed
    )
    colours = _mix(colours, LIPS, lips)
    for rim in eyes:
        eye = pos[rim]
        centre = eye.mean(axis=0)
        medial = np.sign(pos[mouth, 0].mean() - centre[0])  # towards the nose
        inner_x, outer_x = eye[np.argmax(medial * eye[:, 0]), 0], eye[np.argmin(medial * eye[:, 0]), 0]
        w = abs(outer_x - inner_x)
        start, end = inner_x + medial * 0.1 * w, outer_x - medial * 0.2 * w
        t = (pos[:, 0] - start) / (end - start)
        along = (t >= 0) & (t <= 1)
        tc = np.clip(t, 0.0, 1.0)
        line = (
            centre[1]
            + 0.55 * w
            + 0.12
            * w
            * np.sin(np.pi * np.minimum(tc / 0.67, 1.0) / 2)
            * (1 - 0.5 * np.clip((tc - 0.67) / 0.33, 0.0, 1.0))
        )
        thick = (0.4 - 0.24 * tc) * w
        off = np.abs(pos[:, 1] - line) / (thick / 2)
        ends = smoothstep(tc, (0.0, 0.08)) * (1 - smoothstep(tc, (0.9, 1.0)))
        brow = along * (1 - smoothstep(off, (0.6, 1.0))) * ends * (pos[:, 2] > centre[2] - 0.3 * w)
        colours = _mix(colours, BROWS, 0.85 * brow)
        lid = rim[pos[rim, 1] > centre[1]]
        lash_distance, _ = cKDTree(pos[lid]).query(pos)
        colours = _mix(colours, LASHES, 1 - smoothstep(lash_distance, (0.0, LASH_WIDTH * w)))
    return colours


def paint_mouth(primitive: Primitive, front: float, back: float, tongue: np.ndarray | None = None) -> np.ndarray:
    """``COLOR_0`` of a primitive inside the mouth: darker with depth from ``front`` (the lips' z)
    to ``back`` (the throat's z); ``tongue`` (per-vertex weights 0..1) tints the tongue."""
    depth = np.clip((front - primitive.positions[:, 2]) / max(front - back, 1e-9), 0.0, 1.0)
    light = MOUTH_DEPTH[1] - (MOUTH_DEPTH[1] - MOUTH_DEPTH[0]) * np.sqrt(depth)
    colours = np.repeat(light[:, None], 3, axis=1)
    if tongue is not None:
        colours *= 1 + (TONGUE - 1) * tongue[:, None]
    return colours
