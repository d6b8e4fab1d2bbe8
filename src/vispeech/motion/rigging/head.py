"""A head made ready for vispeech: tongue morph targets, a mouth and looks added to a copy of a GLB.

:func:`prepare_head` adds to a head what it lacks of what vispeech's tracks drive and a viewer
should see: the tongue channels' morph targets, built from the head's own tongue geometry
(:mod:`vispeech.motion.rigging.tongue`), with the tongue laid low at rest and the upper front
teeth where a speaker's show (:mod:`vispeech.motion.rigging.mouth`); and, on a head with flat
materials, vertex colours for the lips, brows, lash line, complexion and the mouth's depth
(:mod:`vispeech.motion.rigging.head_paint`). The rest of the file is kept as it is (compressed
data stays compressed).

vispeech ships one head ready, :data:`DEFAULT_HEAD`, the one ``vispeech serve``, ``convert`` and
``stimuli render`` use when given none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.rigging.face import Face, find_face
from vispeech.motion.rigging.glb import Primitive, read_primitives, skin_primitive
from vispeech.motion.rigging.glb_edit import NewPrimitive, extended_glb
from vispeech.motion.rigging.head_hair import Hairline, eyelashes, find_hairline, hair_cap, under_hair
from vispeech.motion.rigging.head_paint import (
    MUCOSA,
    ROOTS,
    SKIN_SHEEN,
    WALLS,
    mouth_front,
    mouth_light,
    paint_mouth,
    paint_skin,
)
from vispeech.motion.rigging.mouth import cavity, mouth_parts, shown_teeth
from vispeech.motion.rigging.tongue import Tongue, find_tongue, lowered, tongue_targets

DEFAULT_HEAD = Path(__file__).parent / "data" / "ict_head.glb"
"""The shipped head: ICT-FaceKit's generic neutral face with its 51 ARKit expression shapes (USC
Institute for Creative Technologies, MIT licence: ``LICENSE-ICT-FaceKit.txt`` beside it),
meshoptimizer-compressed, as ``vispeech rig prepare`` writes it from ``shared/assets/ict_head.glb``
(tongue morph targets, mouth, hair and eyelashes added, flat materials painted): run that again
when :func:`prepared_head` changes."""

HEAD_CREDIT = "3D head: ICT-FaceKit (USC ICT), MIT licence"
"""The credit line shown under :data:`DEFAULT_HEAD`."""


@dataclass
class HeadReport:
    """What :func:`prepare_head` did: morph targets added by name, the primitives painted or reshaped, the
    primitives added (hair, eyelashes), and why anything was left out."""

    targets: list[str] = field(default_factory=list)
    painted: list[str] = field(default_factory=list)
    reshaped: list[str] = field(default_factory=list)
    added: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def prepare_head(base_glb: str | os.PathLike, out_path: str | os.PathLike) -> HeadReport:
    """Write :func:`prepared_head` of ``base_glb`` to ``out_path`` (atomically); its report."""
    data, report = prepared_head(base_glb)
    with atomic_output_file(out_path) as tmp:
        tmp.write_bytes(data)
    return report


def prepared_head(base_glb: str | os.PathLike) -> tuple[bytes, HeadReport]:
    """The bytes of a copy of ``base_glb`` with the tongue morph targets it lacks, its mouth made
    ready and, where its materials are flat, painted vertex colours (see the module docstring),
    and what was added. Raises :class:`VispeechError` for a file that is not a head with ARKit
    morph targets."""
    primitives = read_primitives(base_glb)
    skin = skin_primitive(primitives, base_glb)
    report = HeadReport()
    face: Face | None = None
    try:
        face = find_face(skin)
    except VispeechError as exc:
        report.notes.append(f"{skin.name}: not painted: {exc}")
    tongue = _tongue(primitives, skin, face, base_glb, report)
    positions = {}
    if tongue is not None:
        for reshaped in (tongue.primitive, tongue.teeth):
            key = (reshaped.mesh, reshaped.index)
            if reshaped.positions is not next(p for p in primitives if (p.mesh, p.index) == key).positions:
                positions[key] = reshaped.positions
                report.reshaped.append(reshaped.name)
        shapes = {(r.mesh, r.index): r for r in (tongue.primitive, tongue.teeth)}
        primitives = [shapes.get((p.mesh, p.index), p) for p in primitives]
    hairline = find_hairline(face, skin, _scalp(primitives, skin)) if face is not None and not skin.coloured else None
    painted = _paint(primitives, skin, face, tongue, hairline, report)
    added = _grown(primitives, skin, face, hairline, report)
    targets = {}
    if tongue is not None:
        offsets = tongue_targets(tongue)
        if offsets:
            targets[(tongue.primitive.mesh, tongue.primitive.index)] = offsets
            report.targets = list(offsets)
        else:
            report.notes.append("the head already has every tongue morph target")
    skins = [p for p in [skin, *_scalp(primitives, skin)] if (p.mesh, p.index) in painted]
    data = extended_glb(
        base_glb,
        targets=targets,
        attributes=painted,
        positions=positions,
        added={skin.mesh: added},
        extensions={(p.mesh, p.index): {"KHR_materials_sheen": SKIN_SHEEN} for p in skins},
    )
    return data, report


def _tongue(
    primitives: list[Primitive], skin: Primitive, face: Face | None, source: str | os.PathLike, report: HeadReport
) -> Tongue | None:
    """The head's tongue lying low, with the upper front teeth lowered to show; None (with a note) without one."""
    try:
        tongue = find_tongue(primitives, source)
    except VispeechError as exc:
        report.notes.append(f"no tongue morph targets: {exc}")
        return None
    teeth = shown_teeth(tongue.teeth, skin, face) if face is not None else None
    if teeth is not None:
        tongue = replace(tongue, teeth=replace(tongue.teeth, positions=teeth))
    return lowered(tongue)


def _scalp(primitives: list[Primitive], skin: Primitive) -> list[Primitive]:
    """The primitives besides the skin that hair may grow from: neither inside the mouth nor coloured (eyes)."""
    parts = mouth_parts(primitives)
    return [p for p in primitives if p is not skin and not p.coloured and not any(p is q for q in parts)]


def _grown(
    primitives: list[Primitive], skin: Primitive, face: Face | None, hairline: Hairline | None, report: HeadReport
) -> list[NewPrimitive]:
    """Hair and eyelashes for a head with flat materials and none named for them."""
    names = " ".join(p.name.lower() for p in primitives)
    grown = []
    if hairline is not None and "hair" not in names:
        cap = hair_cap(hairline, [skin, *_scalp(primitives, skin)])
        if cap is not None:
            grown.append(cap)
    if face is not None and not skin.coloured and "lash" not in names:
        grown.append(eyelashes(skin, face))
    report.added = [p.name for p in grown]
    return grown


def _paint(
    primitives: list[Primitive],
    skin: Primitive,
    face: Face | None,
    tongue: Tongue | None,
    hairline: Hairline | None,
    report: HeadReport,
) -> dict[tuple[int, int], dict[str, np.ndarray]]:
    """``COLOR_0`` of the skin and the scalp (darkened under the hair), and ``COLOR_0`` and ``_OCCLUSION``
    of the mouth's parts and the cavity's walls, for those not coloured already."""
    painted: dict[tuple[int, int], dict[str, np.ndarray]] = {}
    parts = mouth_parts(primitives)
    walls = cavity(primitives, skin)
    front = mouth_front(skin, face, parts)
    scalp = [p for p in _scalp(primitives, skin) if (p.mesh, p.index) in walls or hairline is not None]
    on_scalp = {(p.mesh, p.index) for p in scalp}
    for primitive in [skin, *parts, *scalp]:
        if primitive.coloured:
            report.notes.append(f"{primitive.name}: already coloured (a texture or vertex colours), not painted")
            continue
        key = (primitive.mesh, primitive.index)
        if primitive is skin:
            if face is None:
                continue
            painted[key] = {"COLOR_0": paint_skin(skin, face)}
        elif front is None:
            continue
        else:
            everywhere = np.full(len(primitive.positions), key not in on_scalp)
            inside = walls.get(key, everywhere)
            is_tongue = tongue is not None and key == (tongue.primitive.mesh, tongue.primitive.index)
            tint = WALLS if key in walls else np.ones(3) if _is_teeth(primitive) else MUCOSA
            rgb, light = np.ones((len(inside), 3)), np.ones(len(inside))
            weights = tongue.weights[inside] if is_tongue and tongue is not None else None
            rgb[inside] = paint_mouth(primitive.positions[inside], front, weights, tint)
            light[inside] = mouth_light(primitive.positions[inside], front)
            painted[key] = {"COLOR_0": rgb, "_OCCLUSION": light}
        if hairline is not None and (primitive is skin or key in on_scalp):
            rgb = painted[key]["COLOR_0"]
            painted[key]["COLOR_0"] = rgb + (ROOTS - rgb) * under_hair(hairline, primitive.positions)[:, None]
        report.painted.append(primitive.name)
    return painted


def _is_teeth(primitive: Primitive) -> bool:
    return "teeth" in primitive.name.lower() or "tooth" in primitive.name.lower()
