"""A head made ready for vispeech: tongue morph targets and painted looks added to a copy of a GLB.

:func:`prepare_head` adds to a head what it lacks of what vispeech's tracks drive and a viewer
should see: the tongue channels' morph targets, built from the head's own tongue geometry
(:mod:`vispeech.motion.rigging.tongue`), and, on a head with flat materials, vertex colours for the
lips, brows, lash line and the mouth's depth (:mod:`vispeech.motion.rigging.head_paint`). The rest of the
file is kept as it is (compressed data stays compressed).

vispeech ships one head ready, :data:`DEFAULT_HEAD`, the one ``vispeech serve``, ``convert`` and
``stimuli render`` use when given none.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.rigging.glb import read_primitives, skin_primitive
from vispeech.motion.rigging.glb_edit import extended_glb
from vispeech.motion.rigging.head_paint import paint_mouth, paint_skin
from vispeech.motion.rigging.tongue import tongue_targets

DEFAULT_HEAD = Path(__file__).parent / "data" / "ict_head.glb"
"""The shipped head: ICT-FaceKit's generic neutral face with its 51 ARKit expression shapes (USC
Institute for Creative Technologies, MIT licence: ``LICENSE-ICT-FaceKit.txt`` beside it),
meshoptimizer-compressed, as ``vispeech rig prepare`` writes it from ``shared/assets/ict_head.glb``
(tongue morph targets added, flat materials painted): run that again when :func:`prepared_head`
changes."""

HEAD_CREDIT = "3D head: ICT-FaceKit (USC ICT), MIT licence"
"""The credit line shown under :data:`DEFAULT_HEAD`."""

MOUTH_PARTS = ("tongue", "gum", "teeth", "tooth")
"""Words in a primitive's material or mesh name that put it inside the mouth."""


@dataclass
class HeadReport:
    """What :func:`prepare_head` added: morph targets by name, the primitives painted, and why
    anything was left out."""

    targets: list[str] = field(default_factory=list)
    painted: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def prepare_head(base_glb: str | os.PathLike, out_path: str | os.PathLike) -> HeadReport:
    """Write :func:`prepared_head` of ``base_glb`` to ``out_path`` (atomically); its report."""
    data, report = prepared_head(base_glb)
    with atomic_output_file(out_path) as tmp:
        tmp.write_bytes(data)
    return report


def prepared_head(base_glb: str | os.PathLike) -> tuple[bytes, HeadReport]:
    """The bytes of a copy of ``base_glb`` with the tongue morph targets it lacks and, where its
    materials are flat, painted vertex colours (see the module docstring), and what was added.
    Raises :class:`VispeechError` for a file that is not a head with ARKit morph targets."""
    primitives = read_primitives(base_glb)
    skin = skin_primitive(primitives, base_glb)
    report = HeadReport()
    targets, colours = {}, {}
    tongue = None
    try:
        tongue, offsets = tongue_targets(primitives, base_glb)
    except VispeechError as exc:
        report.notes.append(f"no tongue morph targets: {exc}")
    else:
        if offsets:
            targets[(tongue.primitive.mesh, tongue.primitive.index)] = offsets
            report.targets = list(offsets)
        else:
            report.notes.append("the head already has every tongue morph target")
    mouth = [p for p in primitives if any(word in p.name.lower() for word in MOUTH_PARTS)]
    if mouth:
        front = max(p.positions[:, 2].max() for p in mouth)
        back = min(p.positions[:, 2].min() for p in mouth)
    for primitive in [skin, *mouth]:
        if primitive.coloured:
            report.notes.append(f"{primitive.name}: already coloured (a texture or vertex colours), not painted")
            continue
        if primitive is skin:
            try:
                colours[(skin.mesh, skin.index)] = paint_skin(skin)
            except VispeechError as exc:
                report.notes.append(f"{skin.name}: not painted: {exc}")
                continue
        else:
            weights = tongue.weights if tongue is not None and primitive is tongue.primitive else None
            colours[(primitive.mesh, primitive.index)] = paint_mouth(primitive, front, back, weights)
        report.painted.append(primitive.name)
    attributes = {key: {"COLOR_0": rgb} for key, rgb in colours.items()}
    return extended_glb(base_glb, targets=targets, attributes=attributes), report
