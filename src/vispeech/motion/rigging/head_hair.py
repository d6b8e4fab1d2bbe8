"""Hair and eyelashes for a bald head, grown from its own skin.

- **Hairline** (:func:`find_hairline`): around the head's vertical axis (through the middle of
  its skin and scalp, seen from above), at azimuth ``φ`` (0 in front), the hair starts at a
  height ``h(φ)`` set by the face's features (:class:`~vispeech.motion.rigging.face.Face`; ``ED``
  the eye distance; the brows 0.25 ED above the eyes): 0.45 ED above the brows in front, 0.3
  ED at the temples, down to 0.35 ED below the eyes in the sideburns before the ears, up over
  the ears (0.25 ED above the eyes), and down to 0.15 ED above the mouth at the nape (linear
  between, :data:`HAIRLINE`).
- **Hair cap** (:func:`hair_cap`): the skin and scalp above the hairline, welded into one
  surface and pushed out along its normals by the hair's thickness (0.4 mm at the hairline,
  rising over 2.5 cm to 4 mm at the sides and 10 mm on top), dark brown, with strands: a
  generated texture (:func:`strand_texture`) of fine strands and clumps running away from the
  crown (its texture coordinates: the azimuth around the axis from the head's centre to the
  crown, a point above and behind the top, and the angle from that axis). The hairline is
  ragged: the cap's alpha fades in over 6 mm above the hairline and each strand's alpha
  differs, cut at 0.5 (alpha mode MASK). It moves with the skin it grew from (its morph
  targets are that skin's: the forehead's under a raised brow).
- **Eyelashes** (:func:`eyelashes`): along each upper lid (the eye hole's rim above its centre),
  :data:`UPPER_LASHES` curved, tapering ribbons from the lid's front edge (in front of the
  rim, the lowest point of the lid), 0.05 ED long at the inner corner rising to 0.1 ED two
  thirds of the way out, pointing forward and curling up (:data:`LASH_ANGLES`), splayed
  outwards at the outer end; along each lower lid :data:`LOWER_LASHES` shorter ones pointing
  down; each a little longer or shorter, steeper or flatter than the next (a seeded draw).
  Each moves with the lid vertex it grows from.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.face import Face
from vispeech.motion.rigging.glb import Primitive
from vispeech.motion.rigging.glb_edit import NewPrimitive

HAIRLINE = ((0.0, "brow", 0.45), (30.0, "brow", 0.42), (55.0, "brow", 0.3), (75.0, "eye", 0.15),
            (84.0, "eye", -0.3), (92.0, "eye", -0.35), (96.0, "eye", 0.25), (114.0, "eye", 0.25),
            (126.0, "eye", -0.35), (150.0, "mouth", 0.2), (180.0, "mouth", 0.15))  # fmt: skip
"""``(|φ| in degrees, feature, ED above it)``: the hairline's height around the head."""
HAIR_COLOUR = (0.05, 0.032, 0.022, 1.0)
HAIR_THICKNESS = (0.0004, 0.004, 0.01, 0.025)  # metres: at the hairline, at the sides, on top; the rise
HAIR_FADE = 0.006
TEXTURE_SIZE = (512, 32)
UPPER_LASHES, LOWER_LASHES = 28, 14
LASH_ANGLES = ((15.0, 55.0), (-25.0, -45.0))
"""Degrees above the forward direction of the upper and the lower lashes' two halves (they curl)."""
LASH_COLOUR = (0.02, 0.016, 0.014, 1.0)


@dataclass(frozen=True)
class Hairline:
    """Where the hair starts: the head's ``centre`` (its axis vertical through it), the ``crown``
    (the point the hair grows away from) and the heights of the hairline at azimuths
    (``degrees``, ``heights``, scene units)."""

    centre: np.ndarray
    crown: np.ndarray
    degrees: np.ndarray
    heights: np.ndarray
    top: float

    def above(self, points: np.ndarray) -> np.ndarray:
        """How far each of ``points`` (n × 3) is above the hairline (metres, negative below it)."""
        phi = np.degrees(np.abs(np.arctan2(points[:, 0] - self.centre[0], points[:, 2] - self.centre[2])))
        return points[:, 1] - np.interp(phi, self.degrees, self.heights)


def find_hairline(face: Face, skin: Primitive, scalp: list[Primitive]) -> Hairline:
    """The hairline of a head (module docstring) from its ``face``, its ``skin`` and the rest of its ``scalp``."""
    pos = skin.positions
    everything = np.concatenate([pos, *[p.positions for p in scalp]])
    low, high = everything.min(axis=0), everything.max(axis=0)
    eye = float(np.mean([pos[rim, 1].mean() for rim in face.eyes]))
    brow = eye + 0.25 * face.eye_distance
    levels = {"brow": brow, "eye": eye, "mouth": float(pos[face.mouth, 1].mean())}
    centre = np.array([pos[face.mouth, 0].mean(), eye, (low[2] + high[2]) / 2])
    crown = centre + np.array([0.0, high[1] - eye, -0.35 * (high[2] - low[2])])
    degrees = np.array([d for d, _, _ in HAIRLINE])
    heights = np.array([levels[feature] + k * face.eye_distance for _, feature, k in HAIRLINE])
    return Hairline(centre, crown, degrees, heights, float(high[1]))


def under_hair(hairline: Hairline, positions: np.ndarray) -> np.ndarray:
    """How much the hair covers each vertex at ``positions`` (0..1): fully 3 mm above the hairline."""
    return smoothstep(hairline.above(positions), (-0.001, 0.003))


def hair_cap(hairline: Hairline, surfaces: list[Primitive]) -> NewPrimitive | None:
    """The hair cap grown from ``surfaces`` (the skin and the scalp) above ``hairline`` (module
    docstring); None when no skin lies above it."""
    points, triangles, sources = _welded_above(hairline, surfaces)
    if not len(triangles):
        return None
    normals = _vertex_normals(points, triangles)
    outward = np.sign(np.sum(normals * (points - hairline.centre), axis=1).sum()) or 1.0
    normals *= outward
    above = hairline.above(points)
    height = smoothstep(points[:, 1], (hairline.centre[1], hairline.top))
    full = HAIR_THICKNESS[1] + (HAIR_THICKNESS[2] - HAIR_THICKNESS[1]) * height
    thickness = HAIR_THICKNESS[0] + (full - HAIR_THICKNESS[0]) * smoothstep(above, (0.0, HAIR_THICKNESS[3]))
    shell = points + normals * thickness[:, None]
    uv = _crown_coordinates(hairline, shell)
    rows, uv, triangles = _unwrapped(uv, triangles)
    alpha = smoothstep(above[rows], (0.0, HAIR_FADE))
    colours = np.column_stack([np.ones((len(rows), 3)), alpha])
    targets: dict[str, np.ndarray] = {}
    for name in {n for surface, _ in sources for n in surface.targets}:
        moved = np.zeros((len(points), 3))
        for surface, (mine, theirs) in sources:
            if name in surface.targets:
                moved[mine] = surface.targets[name][theirs]
        targets[name] = moved[rows]
    return NewPrimitive(
        name="vispeech_hair",
        positions=shell[rows],
        normals=normals[rows],
        triangles=triangles,
        colours=colours,
        targets=targets,
        base_colour=HAIR_COLOUR,
        roughness=0.75,
        alpha_cutoff=0.5,
        uvs=uv,
        texture=strand_texture(),
    )


def _welded_above(
    hairline: Hairline, surfaces: list[Primitive]
) -> tuple[np.ndarray, np.ndarray, list[tuple[Primitive, tuple[np.ndarray, np.ndarray]]]]:
    """The triangles of ``surfaces`` with a vertex above the hairline, as one surface with the vertices
    they share welded (points, triangles, and per surface the welded indices of its vertices and theirs)."""
    points: list[np.ndarray] = []
    triangles, sources = [], []
    count = 0
    for surface in surfaces:
        keep = hairline.above(surface.positions) > -0.002
        chosen = surface.triangles[keep[surface.triangles].any(axis=1)]
        used = np.unique(chosen)
        if not len(used):
            continue
        index = np.full(len(surface.positions), -1)
        index[used] = count + np.arange(len(used))
        points.append(surface.positions[used])
        triangles.append(index[chosen])
        sources.append((surface, (index[used], used)))
        count += len(used)
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), []
    joined = np.concatenate(points)
    _, unique, remap = np.unique(
        np.round(joined / 1e-5).astype(np.int64), axis=0, return_index=True, return_inverse=True
    )
    remap = remap.reshape(-1)
    welded = remap[np.concatenate(triangles)]
    welded = welded[(welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])]
    return joined[unique], welded, [(s, (remap[mine], theirs)) for s, (mine, theirs) in sources]


def _vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle surface."""
    a, b, c = (points[triangles[:, k]] for k in range(3))
    face_normals = np.cross(b - a, c - a)
    normals = np.zeros_like(points)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def _crown_coordinates(hairline: Hairline, points: np.ndarray) -> np.ndarray:
    """Texture coordinates of ``points``: (azimuth around the centre–crown axis / 2π, angle from it / π)."""
    axis = hairline.crown - hairline.centre
    axis /= np.linalg.norm(axis)
    reference = np.cross(axis, [1.0, 0.0, 0.0])
    reference /= np.linalg.norm(reference)
    side = np.cross(axis, reference)
    d = points - hairline.centre
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u = (np.arctan2(d @ side, d @ reference) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(d @ axis, -1.0, 1.0)) / np.pi
    return np.column_stack([u, v])


def _unwrapped(uv: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices of triangles that cross the texture's seam (u from 1 back to 0) doubled with u + 1:
    the source row of each output vertex, the output's texture coordinates and triangles."""
    corners = uv[triangles, 0]
    crossing = corners.max(axis=1) - corners.min(axis=1) > 0.5
    shifted = crossing[:, None] & (corners < 0.5)
    keys = triangles * 2 + shifted
    unique, remap = np.unique(keys.reshape(-1), return_inverse=True)
    rows = unique // 2
    out = uv[rows].copy()
    out[:, 0] += unique % 2
    return rows, out, remap.reshape(-1, 3)


def strand_texture(seed: int = 7) -> bytes:
    """A PNG (grey and alpha, :data:`TEXTURE_SIZE`): strands running down its height, fine ones over
    clumps a few pixels wide, lighter and darker, each with its own alpha (0.6 to 1) for a ragged
    hairline; the same every time (``seed``)."""
    width, height = TEXTURE_SIZE
    rng = np.random.default_rng(seed)
    x = np.arange(width)

    def noise(period: int) -> np.ndarray:
        knots = rng.uniform(-1, 1, width // period + 1)
        knots[-1] = knots[0]
        return np.interp(x / period, np.arange(len(knots)), knots)

    strands = 0.5 * noise(8) + 0.35 * noise(3) + 0.15 * rng.uniform(-1, 1, width)
    along = np.linspace(0, 1, height)[:, None]
    drift = 1.5 * np.sin(2 * np.pi * (along * 0.7 + rng.uniform()))
    grey = np.interp((x[None, :] + drift) % width, x, 0.7 + 0.3 * strands)
    alpha = np.broadcast_to(0.6 + 0.4 * (0.5 + 0.5 * noise(2)), grey.shape)
    pixels = np.clip(np.stack([grey, alpha], axis=-1) * 255, 0, 255).astype(np.uint8)
    raw = b"".join(b"\x00" + row.tobytes() for row in pixels)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 4, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


def eyelashes(skin: Primitive, face: Face) -> NewPrimitive:
    """Upper and lower eyelashes along each eye hole of ``skin`` (module docstring)."""
    pos = skin.positions
    ed = face.eye_distance
    mouth_x = pos[face.mouth, 0].mean()
    rng = np.random.default_rng(3)
    vertices: list[np.ndarray] = []
    normals: list[list[float]] = []
    triangles: list[list[int]] = []
    roots: list[int] = []
    for rim in face.eyes:
        centre = pos[rim].mean(axis=0)
        outward = np.sign(centre[0] - mouth_x)
        for upper in (True, False):
            lid = _lid_margin(pos, rim[(pos[rim, 1] > centre[1]) == upper], upper)
            lid = lid[np.argsort(outward * pos[lid, 0])]  # from the inner corner out
            count = UPPER_LASHES if upper else LOWER_LASHES
            for t in np.linspace(0.06, 0.94, count):
                point, nearest = _along(pos[lid], t)
                length = ed * (0.05 + 0.05 * np.sin(np.pi * min(t / 1.33, 1.0)) if upper else 0.035)
                length *= rng.uniform(0.85, 1.1)
                angles = np.radians(LASH_ANGLES[0 if upper else 1]) + rng.uniform(-0.08, 0.08)
                splay = outward * max(t - 0.5, 0.0) * 0.8
                start = len(vertices)
                for k, angle in enumerate((None, *angles)):
                    if angle is not None:
                        point = point + length / 2 * np.array([splay, np.sin(angle), np.cos(angle)])
                    half = 0.0025 * ed * (1 - 0.4 * k)
                    for side in (-1.0, 1.0):
                        vertices.append(point + np.array([side * half, 0.0, 0.0]))
                        normals.append([0.0, 0.3 if upper else -0.3, 1.0])
                        roots.append(lid[nearest])
                    if k:
                        a = start + 2 * (k - 1)
                        triangles += [[a, a + 1, a + 3], [a, a + 3, a + 2]]
    rows = np.array(roots)
    return NewPrimitive(
        name="vispeech_eyelashes",
        positions=np.array(vertices),
        normals=np.array(normals),
        triangles=np.array(triangles),
        colours=np.ones((len(vertices), 4)),
        targets={name: offsets[rows] for name, offsets in skin.targets.items()},
        base_colour=LASH_COLOUR,
        roughness=0.6,
        double_sided=True,
    )


def _lid_margin(pos: np.ndarray, rim: np.ndarray, upper: bool) -> np.ndarray:
    """The skin vertices along a lid's front edge, where its lashes grow: in front of each vertex of the
    eye hole's ``rim`` (within 1.5 mm across, at least 1 mm forward and 6 mm away), the lowest of the
    upper lid's or the highest of the lower lid's."""
    margin = []
    for r in rim:
        near = (
            (np.abs(pos[:, 0] - pos[r, 0]) < 0.0015)
            & (pos[:, 2] > pos[r, 2] + 0.001)
            & (np.linalg.norm(pos - pos[r], axis=1) < 0.006)
            & ((pos[:, 1] > pos[r, 1] - 0.002) if upper else (pos[:, 1] < pos[r, 1] + 0.002))
        )
        candidates = np.flatnonzero(near)
        if len(candidates):
            heights = pos[candidates, 1]
            margin.append(candidates[np.argmin(heights) if upper else np.argmax(heights)])
        else:
            margin.append(r)
    return np.array(list(dict.fromkeys(margin)))


def _along(points: np.ndarray, t: float) -> tuple[np.ndarray, int]:
    """The point a share ``t`` of the way along the polyline through ``points``, and the nearest of them."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    distance = np.concatenate([[0.0], np.cumsum(steps)])
    at = t * distance[-1]
    point = np.array([np.interp(at, distance, points[:, k]) for k in range(3)])
    return point, int(np.argmin(np.abs(distance - at)))
