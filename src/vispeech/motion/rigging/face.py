"""Where a head's features are, from its skin's holes and morph targets.

A head's skin is a surface with holes: the mouth (the hole ``jawOpen`` moves furthest) and the
eyes (the two ``eyeBlinkLeft``/``eyeBlinkRight`` move furthest); its outer edge (the longest
boundary loop) is where the skin ends at the neck or the scalp. :func:`find_face` finds them;
what :mod:`~vispeech.motion.rigging.head_paint` paints and
:mod:`~vispeech.motion.rigging.head_hair` grows is placed by them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vispeech.errors import VispeechError
from vispeech.motion.rigging.glb import Primitive


@dataclass(frozen=True)
class Face:
    """The features of a head's skin: ``mouth``, the vertex indices around the mouth hole (the
    inner-lip contour) in order along the loop; ``eyes``, each eye hole's rim in loop order,
    the one at smaller x first; ``eye_distance`` (ED, scene units), between the eye holes'
    outer corners."""

    mouth: np.ndarray
    eyes: tuple[np.ndarray, np.ndarray]
    eye_distance: float


def boundary_loops(primitive: Primitive) -> list[np.ndarray]:
    """The vertex indices of each boundary loop of a primitive's triangles (edges used by one
    triangle), each in order along the loop, longest first."""
    edges = np.sort(primitive.edges, axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    rim = unique[counts == 1]
    neighbours: dict[int, list[int]] = {}
    for a, b in rim.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in neighbours:
        if start in seen:
            continue
        loop, previous, current = [start], -1, start
        seen.add(start)
        while True:
            step = [n for n in neighbours[current] if n != previous and n not in seen]
            if not step:
                break
            previous, current = current, step[0]
            loop.append(current)
            seen.add(current)
        loops.append(np.array(loop))
    return sorted(loops, key=len, reverse=True)


def _moved(skin: Primitive, rim: np.ndarray, *names: str) -> float:
    return max(
        (float(np.linalg.norm(skin.targets[name][rim], axis=1).mean()) for name in names if name in skin.targets),
        default=0.0,
    )


def find_face(skin: Primitive) -> Face:
    """The mouth and eye holes of ``skin`` (see the module docstring). Raises :class:`VispeechError`
    when the skin has no mouth hole or no two eye holes."""
    holes = boundary_loops(skin)[1:]
    blink = ("eyeBlinkLeft", "eyeBlinkRight")
    eyes = sorted((rim for rim in holes if _moved(skin, rim, *blink) > 0), key=lambda rim: _moved(skin, rim, *blink))
    eyes = eyes[-2:]
    mouths = [rim for rim in holes if not any(rim is e for e in eyes) and _moved(skin, rim, "jawOpen") > 0]
    if len(eyes) < 2 or not mouths:
        raise VispeechError("found no mouth hole and two eye holes in the skin to place the features by")
    mouth = max(mouths, key=lambda rim: _moved(skin, rim, "jawOpen"))
    pos = skin.positions
    centre_x = pos[mouth, 0].mean()
    outer = [pos[rim][np.argmax(np.abs(pos[rim, 0] - centre_x))] for rim in eyes]
    left, right = sorted(eyes, key=lambda rim: pos[rim, 0].mean())
    return Face(mouth, (left, right), float(np.linalg.norm(outer[0] - outer[1])))
