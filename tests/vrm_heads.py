"""VRM models for the tests, made as a VRM author makes them: a glTF model given a humanoid skeleton's
bone names and expression presets bound to its morph targets.

:func:`vrm_head`: the shipped ICT-FaceKit head (MIT licence) as VRM 1.0 and 0.x, its morph targets
renamed (so that only the VRM's expressions name what they do) or kept ("perfect sync"); the head
hangs from the head bone of a bare humanoid skeleton (every bone a VRM needs, no skin), each preset
binds a mix of its ARKit shapes (:data:`PRESETS`). :func:`vrm_from_valid`: a whole skinned avatar of
the VALID library (University of Central Florida and Google, MIT licence; Microsoft Rocketbox's
facial shapes, no ARKit names) as VRM 0.x, each preset bound to its own viseme, eyelid and smile
shapes (:data:`VALID_PRESETS`). A VRM 0.x model is turned to face -Z, as VRM 0.x models do.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

from vispeech.motion.rigging.head import DEFAULT_HEAD

PRESETS = {
    "aa": {"jawOpen": 0.7, "mouthLowerDownLeft": 0.3, "mouthLowerDownRight": 0.3},
    "ih": {"jawOpen": 0.1, "mouthStretchLeft": 0.6, "mouthStretchRight": 0.6},
    "ou": {"jawOpen": 0.1, "mouthPucker": 0.9, "mouthFunnel": 0.3},
    "ee": {"jawOpen": 0.35, "mouthStretchLeft": 0.4, "mouthStretchRight": 0.4},
    "oh": {"jawOpen": 0.45, "mouthFunnel": 0.8},
    "blink": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0},
    "blinkLeft": {"eyeBlinkLeft": 1.0},
    "blinkRight": {"eyeBlinkRight": 1.0},
    "happy": {"mouthSmileLeft": 0.8, "mouthSmileRight": 0.8, "cheekSquintLeft": 0.6, "cheekSquintRight": 0.6},
    "sad": {"mouthFrownLeft": 0.7, "mouthFrownRight": 0.7, "browInnerUp": 0.6},
}
"""Each expression preset (VRM 1.0 names) and the ARKit shapes it binds, with their weights."""

_VRM0_PRESETS = {"aa": "a", "ih": "i", "ou": "u", "ee": "e", "oh": "o", "blink": "blink",
                 "blinkLeft": "blink_l", "blinkRight": "blink_r", "happy": "joy", "sad": "sorrow"}
_BONES = {  # bone: parent
    "hips": None, "spine": "hips", "chest": "spine", "neck": "chest", "head": "neck",
    **{f"{side}UpperArm": "chest" for side in ("left", "right")},
    **{f"{side}LowerArm": f"{side}UpperArm" for side in ("left", "right")},
    **{f"{side}Hand": f"{side}LowerArm" for side in ("left", "right")},
    **{f"{side}UpperLeg": "hips" for side in ("left", "right")},
    **{f"{side}LowerLeg": f"{side}UpperLeg" for side in ("left", "right")},
    **{f"{side}Foot": f"{side}LowerLeg" for side in ("left", "right")},
}
_MIT = "https://opensource.org/license/mit"


def _read(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length]), data[20 + length :]


def _write(path: Path, gltf: dict, rest: bytes) -> None:
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def vrm_head(path: Path, version: str = "1.0", perfect_sync: bool = False, arkit_expressions: bool = False,
             head: Path = DEFAULT_HEAD) -> Path:
    """Write ``head`` (an ICT-FaceKit head: the shipped one by default) as a VRM ``version`` ("1.0" or
    "0.x") model to ``path``; its morph targets keep their ARKit names only with ``perfect_sync``.
    ``arkit_expressions`` (VRM 0.x): custom expressions named after the ARKit shapes as well, each
    binding its own morph target, as VRoid's perfect-sync tools make them."""
    gltf, rest = _read(head)
    (mesh,) = gltf["meshes"]
    names = mesh["extras"]["targetNames"]
    if not perfect_sync:
        mesh["extras"]["targetNames"] = [f"shape{k:02d}" for k in range(len(names))]
    head_node = next(k for k, node in enumerate(gltf["nodes"]) if node.get("mesh") == 0)
    root = gltf["scenes"][0]["nodes"][0]
    bones = {}
    for bone in _BONES:
        bones[bone] = len(gltf["nodes"])
        gltf["nodes"].append({"name": bone, "children": []})
    for bone, parent in _BONES.items():
        if parent is not None:
            gltf["nodes"][bones[parent]]["children"].append(bones[bone])
    gltf["nodes"][bones["head"]]["children"].append(root)
    gltf["scenes"][0]["nodes"] = [bones["hips"]]
    binds = {
        preset: [(names.index(shape), weight) for shape, weight in shapes.items()] for preset, shapes in PRESETS.items()
    }
    if version == "1.0":
        gltf["extensions"] = {"VRMC_vrm": {
            "specVersion": "1.0",
            "meta": {"name": "ICT-FaceKit head", "version": "1", "authors": ["USC ICT"],
                     "licenseUrl": "https://vrm.dev/licenses/1.0/", "otherLicenseUrl": _MIT},
            "humanoid": {"humanBones": {bone: {"node": node} for bone, node in bones.items()}},
            "expressions": {"preset": {
                preset: {"morphTargetBinds": [{"node": head_node, "index": k, "weight": w} for k, w in pairs]}
                for preset, pairs in binds.items()
            }},
        }}
    else:
        gltf["nodes"][bones["hips"]]["rotation"] = [0.0, 1.0, 0.0, 0.0]  # VRM 0.x faces -Z
        gltf["extensions"] = {"VRM": {
            "specVersion": "0.0",
            "meta": {"title": "ICT-FaceKit head", "version": "1", "author": "USC ICT",
                     "licenseName": "Other", "otherLicenseUrl": _MIT},
            "humanoid": {"humanBones": [{"bone": bone, "node": node} for bone, node in bones.items()]},
            "blendShapeMaster": {"blendShapeGroups": [
                {"name": _VRM0_PRESETS[preset], "presetName": _VRM0_PRESETS[preset],
                 "binds": [{"mesh": 0, "index": k, "weight": 100 * w} for k, w in pairs]}
                for preset, pairs in binds.items()
            ] + [
                {"name": name, "presetName": "unknown", "binds": [{"mesh": 0, "index": k, "weight": 100}]}
                for k, name in enumerate(names) if arkit_expressions
            ]},
        }}
    gltf["extensionsUsed"] = [*gltf["extensionsUsed"], *gltf["extensions"]]
    _write(path, gltf, rest)
    return path
