"""Tongue morph targets for a head, derived from the head's own tongue geometry.

Heads made for ARKit seldom move the tongue except out of the mouth (``tongueOut``), and many
(the ICT head) have none. :func:`find_tongue` finds the tongue, :func:`lowered` lays it low
behind the lower teeth, where a tongue rests, and :func:`tongue_targets` builds the offsets of
:data:`~vispeech.motion.arkit.TONGUE_CHANNELS` that the head lacks, so that the tracks'
tongue channels show:

1. **Finding it.** The tongue lives in the primitive whose material (or mesh) is named for it
   (``tongue``, case-insensitively); the teeth in the one named ``teeth`` or ``tooth``. A head
   may keep the tongue with the gums, the palate and the throat in one mesh (the ICT head
   does), so the tongue is told apart by geometry: a vertex belongs to it as far as it is both
   away from the teeth (weight 0 within 2.5 mm of a tooth, 1 beyond 6 mm: the gums hug the
   teeth) and carried by the lower jaw (its ``jawOpen`` displacement over the lower teeth's
   median: 0 below 0.3, 1 above 0.7: the palate and the throat stay where they are). The
   largest connected part of the vertices with weight over 0.5 is the tongue's core; its
   front is the tip, its back the root.
2. **At rest** (:func:`lowered`) the tongue lies low: a head modelled with the tongue filling
   the mouth (the ICT head's is higher than the lower incisors' edge) shows it as a slab
   between the teeth whenever the jaw opens. The top of its midline over the front 60 % is
   brought to :data:`REST_BELOW_TEETH` below the lower incisors' edge: each vertex goes down
   by that drop times its weight, times its height in its slice of the midline (in tenths of
   the length; 0 at the underside, which stays, 1 at the top: the tongue flattens rather than
   sinking through the floor of the mouth), fading out from 0.6 to 1 of the length (the root
   stays). The channels then raise it from there.
3. **Where it can go.** Along the tongue's midline (within 4 mm of the middle, in 2 mm slices
   from tip to root, each looking 2 mm either side), the roof above it: the lowest point, above
   the tongue's top surface, of whatever does not move with the jaw (palate, upper gums and
   upper teeth); the gap between the two, less 1 mm, is how far the tongue may rise there. The
   tip rises by the smallest gap over the front fifth of the tongue, the body by that over 0.5
   to 0.8 of its length, so that neither goes through the roof.
4. **The shapes**, each offset scaled by the vertex's tongue weight; ``s`` runs from 0 at the
   tip to 1 at the root, ``x`` across over the core's half-width:

   - ``tongueTipUp``: the front rises by the tip's gap (the tip to the alveolar ridge and
     the back of the upper incisors, /t d n l/), fully over ``s`` < 0.15 and gone by 0.5,
     less at the sides (``1 − 0.5 x²``);
   - ``tongueBodyUp``: the body rises by the body's gap (the dorsum to the palate and the
     velum, /k g ŋ/), a smooth bump centred at ``s`` = 0.65 reaching 0 at 0.25 and 1.05,
     almost as much at the sides (``1 − 0.3 x²``);
   - ``tongueBack``: the tongue is drawn back by 12 % and down by 3 % of its length, the
     front most (``1 − 0.4 s``);
   - ``tongueOut`` (when the head has none): the front slides forward past the lower incisors
     by 6 mm and to the height between the upper and lower front teeth, fully at the tip and
     gone by ``s`` = 0.6.

The offsets are in the head's rest pose: with the jaw open the tongue goes down with it, as
the jaw's own morph target takes it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from vispeech.errors import VispeechError
from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.glb import Primitive

GUMS = (0.0025, 0.006)
"""Metres from the nearest tooth over which a vertex goes from gum (weight 0) to tongue (1)."""
JAW_CARRIED = (0.3, 0.7)
"""Share of the lower teeth's ``jawOpen`` displacement over which a vertex goes from fixed to carried."""
CLEARANCE = 0.001
MIDLINE = 0.004
SLICE = 0.002
OUT_REACH = 0.006
REST_BELOW_TEETH = 0.004
"""Metres the resting tongue's top lies below the lower incisors' edge (module docstring, step 2)."""


@dataclass(frozen=True)
class Tongue:
    """A head's tongue: the primitive that holds it, the weight of each of its vertices (0..1), the
    indices of its core's vertices (the largest connected part with weight over 0.5), the teeth,
    and which vertices of both stay put when the jaw opens (palate, throat, upper teeth)."""

    primitive: Primitive
    weights: np.ndarray
    core: np.ndarray
    teeth: Primitive
    fixed: np.ndarray
    fixed_teeth: np.ndarray


def find_tongue(primitives: list[Primitive], source: str | os.PathLike = "the head") -> Tongue:
    """The tongue among a head's ``primitives`` (see the module docstring, step 1). Raises
    :class:`VispeechError` when there is no primitive named for the tongue, none for the teeth,
    or no ``jawOpen`` target to tell the lower jaw by."""
    from scipy.sparse import coo_matrix  # scipy: the `rig` extra, imported only to prepare a head
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    tongue = [p for p in primitives if "tongue" in p.name.lower()]
    teeth = [p for p in primitives if "teeth" in p.name.lower() or "tooth" in p.name.lower()]
    if not tongue:
        raise VispeechError(f"{source}: no mesh or material named for the tongue ('tongue' in its name)")
    if not teeth:
        raise VispeechError(f"{source}: no mesh or material named for the teeth ('teeth' or 'tooth' in its name)")
    primitive, teeth_mesh = tongue[0], teeth[0]
    if "jawOpen" not in primitive.targets or "jawOpen" not in teeth_mesh.targets:
        raise VispeechError(f"{source}: the tongue and the teeth need a jawOpen morph target")
    teeth_drop = np.linalg.norm(teeth_mesh.targets["jawOpen"], axis=1)
    lower = teeth_drop > 0.5 * teeth_drop.max()
    if teeth_drop.max() <= 0 or not lower.any():
        raise VispeechError(f"{source}: jawOpen does not move the teeth")
    carried = np.linalg.norm(primitive.targets["jawOpen"], axis=1) / np.median(teeth_drop[lower])
    fixed, fixed_teeth = (
        carried < 0.1 * JAW_CARRIED[0],
        teeth_drop < 0.1 * JAW_CARRIED[0] * np.median(teeth_drop[lower]),
    )
    distance, _ = cKDTree(teeth_mesh.positions).query(primitive.positions)
    weights = smoothstep(distance, GUMS) * smoothstep(carried, JAW_CARRIED)
    inside = weights > 0.5
    edges = primitive.edges
    edges = edges[inside[edges[:, 0]] & inside[edges[:, 1]]]
    n = len(primitive.positions)
    _, labels = connected_components(
        coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)), directed=False
    )
    sizes = np.bincount(labels[inside], minlength=labels.max() + 1) if inside.any() else np.zeros(1)
    if sizes.max() < 20:
        raise VispeechError(
            f"{source}: found no tongue in {primitive.name!r} (nothing away from the teeth moves with the jaw)"
        )
    core = np.flatnonzero(inside & (labels == sizes.argmax()))
    # vertices outside the core's box (flaps of the floor of the mouth beside the gums) are not the tongue
    low, high = primitive.positions[core].min(axis=0), primitive.positions[core].max(axis=0)
    weights = np.where(
        np.all((primitive.positions >= low - GUMS[1]) & (primitive.positions <= high + GUMS[1]), axis=1), weights, 0.0
    )
    return Tongue(primitive, weights, core, teeth_mesh, fixed, fixed_teeth)


def _lengthwise(tongue: Tongue) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The tongue's core vertices, each vertex's ``s`` (0 at the tip, 1 at the root), and the tip's and the root's z."""
    core = tongue.primitive.positions[tongue.core]
    tip_z, root_z = float(core[:, 2].max()), float(core[:, 2].min())
    s = np.clip((tip_z - tongue.primitive.positions[:, 2]) / (tip_z - root_z), 0.0, 1.0)
    return core, s, tip_z, root_z


def lowered(tongue: Tongue) -> Tongue:
    """``tongue`` resting low behind the lower teeth (module docstring, step 2); as it is when it
    already does or there are no teeth that move with the jaw."""
    teeth = tongue.teeth.positions
    lower = teeth[~tongue.fixed_teeth]
    if not len(lower):
        return tongue
    edge = float(lower[lower[:, 2] > lower[:, 2].max() - 0.004, 1].max())
    positions = tongue.primitive.positions
    core, s, _, _ = _lengthwise(tongue)
    bins = np.linspace(0.0, 1.0, 11)
    midline = np.abs(core[:, 0] - np.median(core[:, 0])) < MIDLINE
    core_s = s[tongue.core]
    slices = [core[midline & (core_s >= a) & (core_s <= b)] for a, b in zip(bins[:-1], bins[1:])]
    middle = [(a + b) / 2 for a, b, part in zip(bins[:-1], bins[1:], slices) if len(part)]
    top = np.array([part[:, 1].max() for part in slices if len(part)])
    bottom = np.array([part[:, 1].min() for part in slices if len(part)])
    front = np.array(middle) <= 0.6
    drop = float((top[front] - (edge - REST_BELOW_TEETH)).max()) if front.any() else 0.0
    if drop <= 0:
        return tongue
    height = (positions[:, 1] - np.interp(s, middle, bottom)) / np.maximum(np.interp(s, middle, top - bottom), 1e-3)
    moved = positions.copy()
    moved[:, 1] -= drop * tongue.weights * np.clip(height, 0.0, 1.0) * (1 - smoothstep(s, (0.6, 1.0)))
    return replace(tongue, primitive=replace(tongue.primitive, positions=moved))


def tongue_targets(tongue: Tongue) -> dict[str, np.ndarray]:
    """The offsets (vertices × 3, scene units) of each tongue channel the primitive of ``tongue``
    (:func:`find_tongue`, perhaps :func:`lowered`) lacks (see the module docstring)."""
    primitive = tongue.primitive
    teeth = tongue.teeth.positions
    roof_points = np.concatenate([primitive.positions[tongue.fixed], teeth[tongue.fixed_teeth]])
    positions = primitive.positions
    core, s, tip_z, root_z = _lengthwise(tongue)
    centre_x = float(np.median(core[:, 0]))
    length = tip_z - root_z
    half_width = float(np.abs(core[:, 0] - centre_x).max())
    x = np.clip((positions[:, 0] - centre_x) / half_width, -1.0, 1.0)
    gap = _gap_along(core, roof_points, centre_x, tip_z, root_z)
    along = np.linspace(0, 1, len(gap))
    tip_lift = float(gap[along <= 0.2].min())
    body_lift = float(gap[(along >= 0.5) & (along <= 0.8)].min())
    w = tongue.weights
    up = np.zeros_like(positions)
    offsets: dict[str, np.ndarray] = {}
    tip = 1 - smoothstep(s, (0.15, 0.5))
    up[:, 1] = w * tip_lift * tip * (1 - 0.5 * x * x)
    offsets["tongueTipUp"] = up.copy()
    body = np.where(np.abs(s - 0.65) < 0.4, np.cos(np.pi / 2 * (s - 0.65) / 0.4) ** 2, 0.0)
    up[:, 1] = w * body_lift * body * (1 - 0.3 * x * x)
    offsets["tongueBodyUp"] = up.copy()
    back = np.zeros_like(positions)
    back[:, 2] = -0.12 * length * w * (1 - 0.4 * s)
    back[:, 1] = -0.03 * length * w * (1 - 0.4 * s)
    offsets["tongueBack"] = back
    if "tongueOut" not in primitive.targets:
        front = teeth[:, 2] > teeth[:, 2].max() - 0.005
        tip_y = float(core[core[:, 2] > tip_z - 0.005, 1].mean())
        upper, lower = teeth[front & tongue.fixed_teeth, 1], teeth[front & ~tongue.fixed_teeth, 1]
        between = 0.5 * (upper.min() + lower.max()) if len(upper) and len(lower) else tip_y
        reach = 1 - smoothstep(s, (0.0, 0.6))
        out = np.zeros_like(positions)
        out[:, 2] = w * (teeth[:, 2].max() + OUT_REACH - tip_z) * reach
        out[:, 1] = w * (between - tip_y) * reach
        offsets["tongueOut"] = out
    return {name: offsets[name] for name in TONGUE_CHANNELS if name in offsets and name not in primitive.targets}


def _gap_along(core: np.ndarray, roof: np.ndarray, centre_x: float, tip_z: float, root_z: float) -> np.ndarray:
    """How far the tongue's top may rise (metres, ≥ 0) in slices from the tip to the root
    (module docstring, step 2); a slice with no roof above takes its neighbours' gap."""
    edges = np.arange(tip_z, root_z - SLICE, -SLICE)
    mid = core[np.abs(core[:, 0] - centre_x) < MIDLINE]
    roof = roof[np.abs(roof[:, 0] - centre_x) < MIDLINE]
    gaps = np.full(len(edges) - 1, np.nan)
    for k, (hi, lo) in enumerate(zip(edges[:-1], edges[1:])):
        top = mid[(mid[:, 2] <= hi + SLICE) & (mid[:, 2] > lo - SLICE), 1]
        if not len(top):
            continue
        above = roof[(roof[:, 2] <= hi + SLICE) & (roof[:, 2] > lo - SLICE) & (roof[:, 1] > top.max()), 1]
        if len(above):
            gaps[k] = max(above.min() - top.max() - CLEARANCE, 0.0)
    known = np.flatnonzero(~np.isnan(gaps))
    if not len(known):
        raise VispeechError("found nothing above the tongue (palate or upper teeth) to raise it to")
    return np.interp(np.arange(len(gaps)), known, gaps[known])
