"""glTF 2.0 export: a morph-target ``weights`` animation added to a copy of a GLB model.

The model's meshes must name their morph targets (``mesh.extras.targetNames``, as Blender
and most exporters write it) with ARKit names; ``eyeBlink_L``-style ``_L``/``_R`` suffixes and
``blendShape1.jawOpen``-style prefixes are accepted, case-insensitively. The existing binary
chunk is kept byte for byte (compressed or quantized meshes are not decoded); the animation's
times and weights are appended to it. pygltflib reads and writes the JSON.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pygltflib

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.track import Track

_ARKIT_BY_KEY = {name.lower(): name for name in ARKIT_NAMES}
_FLOAT = 5126


def arkit_target_name(target: str) -> str | None:
    """The ARKit name a morph target stands for (``"blendShape1.eyeBlink_L"`` -> ``"eyeBlinkLeft"``)."""
    key = target.rsplit(".", 1)[-1].strip().lower()
    if key.endswith("_l"):
        key = key[:-2] + "left"
    elif key.endswith("_r"):
        key = key[:-2] + "right"
    return _ARKIT_BY_KEY.get(key)


def write_gltf_animation(
    track: Track, base_glb: str | os.PathLike, out_path: str | os.PathLike, name: str = "speech"
) -> None:
    """Write a copy of ``base_glb`` with ``track`` added as the animation ``name``.

    Every node whose mesh has ARKit-named morph targets gets one ``weights`` channel with a
    LINEAR sampler: input times ``k / fps`` seconds (k = 0 .. n_frames-1, from the track's
    first frame), output the weights of all the mesh's targets in target order for each frame
    (targets with no ARKit name, or a channel the track lacks, stay 0). Written atomically.
    """
    gltf = _load(base_glb)
    if gltf.buffers and gltf.buffers[0].uri is not None:
        raise VispeechError(f"{base_glb}: its first buffer is an external file; use a .glb with its data embedded")
    meshes = _animated_meshes(gltf)
    if not meshes:
        raise VispeechError(f"{base_glb} has no mesh with ARKit-named morph targets (mesh.extras.targetNames)")
    nodes = [(i, node.mesh) for i, node in enumerate(gltf.nodes) if node.mesh in meshes]
    if not nodes:
        raise VispeechError(f"{base_glb}: no node uses the meshes with ARKit-named morph targets")

    blob = bytearray(gltf.binary_blob() or b"")
    if not gltf.buffers:
        gltf.buffers.append(pygltflib.Buffer(byteLength=0))
    times = (np.arange(track.n_frames) / track.fps).astype(np.float32)
    time_accessor = _append_accessor(gltf, blob, times)
    outputs: dict[int, int] = {}
    animation = pygltflib.Animation(name=name, channels=[], samplers=[])
    for node, mesh in nodes:
        if mesh not in outputs:
            names = meshes[mesh]
            weights = np.zeros((track.n_frames, len(names)), dtype=np.float32)
            for j, arkit in enumerate(names):
                if arkit is not None and arkit in track.channels:
                    weights[:, j] = track[arkit]
            outputs[mesh] = _append_accessor(gltf, blob, weights.reshape(-1))
        animation.samplers.append(
            pygltflib.AnimationSampler(input=time_accessor, output=outputs[mesh], interpolation="LINEAR"))
        animation.channels.append(pygltflib.AnimationChannel(
            sampler=len(animation.samplers) - 1, target=pygltflib.AnimationChannelTarget(node=node, path="weights")))
    gltf.animations.append(animation)
    blob.extend(b"\x00" * (-len(blob) % 4))
    gltf.buffers[0].byteLength = len(blob)
    with atomic_output_file(out_path) as tmp:
        tmp.write_bytes(_glb_bytes(gltf, bytes(blob)))


def _load(path: str | os.PathLike) -> pygltflib.GLTF2:
    path = Path(path)
    if not path.is_file():
        raise VispeechError(f"base model not found: {path}")
    try:
        with path.open("rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise VispeechError(f"cannot read {path}: {exc.strerror or exc}") from None
    if magic != b"glTF":
        raise VispeechError(f"{path} is not a binary glTF (.glb) file")
    try:
        return pygltflib.GLTF2().load_binary(str(path))
    except Exception as exc:  # pygltflib raises assorted exception types on malformed files
        raise VispeechError(f"cannot load {path}: {' '.join(str(exc).split()) or type(exc).__name__}") from None


def _glb_bytes(gltf: pygltflib.GLTF2, blob: bytes) -> bytes:
    """The GLB container: header, JSON chunk (space-padded), BIN chunk ``blob`` (4-byte aligned).

    Written here rather than by pygltflib's ``save_binary``, which repacks every buffer view
    into one buffer and so breaks EXT_meshopt_compression's fallback buffers.
    """
    text = gltf.gltf_to_json(separators=(",", ":"), indent=None).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\x00") + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _animated_meshes(gltf: pygltflib.GLTF2) -> dict[int, list[str | None]]:
    """Mesh index -> ARKit name (or None) of each morph target, for meshes with any ARKit target."""
    found = {}
    for index, mesh in enumerate(gltf.meshes):
        if not mesh.primitives or not mesh.primitives[0].targets:
            continue
        names = (mesh.extras or {}).get("targetNames") or (mesh.primitives[0].extras or {}).get("targetNames")
        if not isinstance(names, list) or len(names) != len(mesh.primitives[0].targets):
            continue
        arkit = [arkit_target_name(str(n)) for n in names]
        if any(arkit):
            found[index] = arkit
    return found


def _append_accessor(gltf: pygltflib.GLTF2, blob: bytearray, data: np.ndarray) -> int:
    """Append float32 scalars as a new buffer view and accessor in buffer 0; return the accessor index."""
    blob.extend(b"\x00" * (-len(blob) % 4))
    raw = np.ascontiguousarray(data, dtype="<f4").tobytes()
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
    blob.extend(raw)
    gltf.accessors.append(pygltflib.Accessor(
        bufferView=len(gltf.bufferViews) - 1, componentType=_FLOAT, count=int(data.size), type="SCALAR",
        min=[float(data.min())], max=[float(data.max())]))
    return len(gltf.accessors) - 1
