"""The inside of a head's mouth: its parts, its cavity, and upper teeth that show as a speaker's do.

- **Parts**: the primitives whose material (or mesh) is named for the tongue, gums or teeth
  (:data:`MOUTH_PARTS`).
- **Cavity**: the walls of the mouth that other primitives hold (the ICT head keeps its inner
  cheeks, floor and throat, a closed bag, in its back-of-head primitive): every connected part
  of a primitive but the skin that lies within the mouth parts' box, grown by
  :data:`CAVITY_MARGIN`. :mod:`~vispeech.motion.rigging.head_paint` darkens it with depth as
  it does the parts.
- **Upper teeth**: a speaker's upper incisors show below the upper lip when the lips part
  (1 to 3.5 mm at rest, more on open vowels, where the upper lip of a head moves down with the
  jaw); a head whose upper incisors end near the lip line shows a slit there instead.
  :func:`shown_teeth` lowers the upper front teeth (those ``jawOpen`` does not move, within
  12 mm of the front, fading out by 20 mm) so that their edge is :data:`TEETH_SHOWN` below the
  upper lip's lowest point at rest (in the middle, in front of the mouth hole's rim
  (:func:`~vispeech.motion.rigging.face.find_face`), of what ``jawOpen`` moves less than 30 %
  as far as the rim); teeth already that low stay.
"""

from __future__ import annotations

import numpy as np

from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.face import Face
from vispeech.motion.rigging.glb import Primitive

MOUTH_PARTS = ("tongue", "gum", "teeth", "tooth")
"""Words in a primitive's material or mesh name that put it inside the mouth."""
CAVITY_MARGIN = 0.005
TEETH_SHOWN = 0.004
FRONT_TEETH = (0.012, 0.02)


def mouth_parts(primitives: list[Primitive]) -> list[Primitive]:
    """The primitives named for the tongue, gums or teeth (:data:`MOUTH_PARTS`)."""
    return [p for p in primitives if any(word in p.name.lower() for word in MOUTH_PARTS)]


def cavity(primitives: list[Primitive], skin: Primitive) -> dict[tuple[int, int], np.ndarray]:
    """Per primitive (``(mesh, index)``) but the skin and the mouth parts, the mask of its vertices that
    make the mouth's walls (see the module docstring); primitives with none are left out."""
    from scipy.sparse import coo_matrix  # scipy: the `rig` extra, imported only to prepare a head
    from scipy.sparse.csgraph import connected_components

    parts = mouth_parts(primitives)
    if not parts:
        return {}
    low = np.min([p.positions.min(axis=0) for p in parts], axis=0) - CAVITY_MARGIN
    high = np.max([p.positions.max(axis=0) for p in parts], axis=0) + CAVITY_MARGIN
    found = {}
    for primitive in primitives:
        if primitive is skin or any(primitive is p for p in parts) or not len(primitive.triangles):
            continue
        edges = primitive.edges
        n = len(primitive.positions)
        count, labels = connected_components(
            coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)), directed=False
        )
        inside = np.all((primitive.positions >= low) & (primitive.positions <= high), axis=1)
        walls = [k for k in range(count) if inside[labels == k].all()]
        if walls:
            found[(primitive.mesh, primitive.index)] = np.isin(labels, walls)
    return found


def upper_teeth(teeth: Primitive) -> np.ndarray:
    """The mask of the teeth that stay put when the jaw opens (all of them without ``jawOpen``)."""
    drop = np.linalg.norm(teeth.targets["jawOpen"], axis=1) if "jawOpen" in teeth.targets else None
    if drop is None or drop.max() <= 0:
        return np.ones(len(teeth.positions), dtype=bool)
    return drop < 0.03 * drop.max()


def shown_teeth(teeth: Primitive, skin: Primitive, face: Face) -> np.ndarray | None:
    """Rest positions of ``teeth`` with the upper front teeth lowered (see the module docstring), or
    None when they already show."""
    pos = teeth.positions
    upper = upper_teeth(teeth)
    front_z = pos[upper, 2].max() if upper.any() else None
    if front_z is None:
        return None
    lip = _lip_line(skin, face)
    if lip is None:
        return None
    incisors = upper & (pos[:, 2] > front_z - 0.004)
    drop = float(pos[incisors, 1].min() - (lip - TEETH_SHOWN))
    if drop <= 0:
        return None
    weight = upper * smoothstep(pos[:, 2], (front_z - FRONT_TEETH[1], front_z - FRONT_TEETH[0]))
    lowered = pos.copy()
    lowered[:, 1] -= drop * weight
    return lowered


def _lip_line(skin: Primitive, face: Face) -> float | None:
    """The height of the upper lip's lowest point at rest, in the middle (module docstring)."""
    pos = skin.positions
    rim = pos[face.mouth]
    jaw = np.linalg.norm(skin.targets["jawOpen"], axis=1) if "jawOpen" in skin.targets else np.zeros(len(pos))
    upper = (
        (np.abs(pos[:, 0] - np.median(rim[:, 0])) < 0.002)
        & (pos[:, 2] > rim[:, 2].max())
        & (pos[:, 1] > rim[:, 1].min())
        & (pos[:, 1] < rim[:, 1].max())
        & (jaw < 0.3 * jaw[face.mouth].max())
    )
    return float(pos[upper, 1].min()) if upper.any() else None
