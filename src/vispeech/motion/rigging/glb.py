"""GLB models with ARKit morph targets: a head's primitives and morph geometry read back
(:func:`read_primitives`, :func:`read_morph_mesh`), and the checked loading, decoding and
packing that :mod:`vispeech.motion.formats.gltf` writes its animations with and
:mod:`vispeech.motion.rigging.glb_edit` a head's additions.

The model's meshes must name their morph targets (``mesh.extras.targetNames``, as Blender
and most exporters write it) with ARKit names (or vispeech's tongue channels,
:data:`~vispeech.motion.arkit.MORPH_NAMES`); ``eyeBlink_L``-style ``_L``/``_R`` suffixes and
``blendShape1.jawOpen``-style prefixes are accepted, case-insensitively (:func:`target_channel`).
The existing binary data is kept byte for byte, except where it is decoded
(:func:`decompressed`: meshoptimizer-compressed buffer views, ``EXT_meshopt_compression``,
as gltfpack writes them; the ``meshopt`` package); quantized attributes
(``KHR_mesh_quantization``) stay as they are. New data is appended. pygltflib reads and
writes the JSON.
"""

from __future__ import annotations

import os
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
import pygltflib

from vispeech.errors import VispeechError
from vispeech.files import read_bytes
from vispeech.limits import MAX_GLB_BYTES, parse_json
from vispeech.motion.arkit import MORPH_NAMES

_CHANNEL_BY_KEY = {name.lower(): name for name in MORPH_NAMES}
FLOAT = 5126
"""glTF's component type of 32-bit floats."""


def target_channel(target: str) -> str | None:
    """The channel a morph target stands for (``"blendShape1.eyeBlink_L"`` -> ``"eyeBlinkLeft"``), one of
    :data:`~vispeech.motion.arkit.MORPH_NAMES`, or None."""
    key = target.rsplit(".", 1)[-1].strip().lower()
    if key.endswith("_l"):
        key = key[:-2] + "left"
    elif key.endswith("_r"):
        key = key[:-2] + "right"
    return _CHANNEL_BY_KEY.get(key)


_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


@dataclass(frozen=True)
class MorphMesh:
    """One primitive of a model with ARKit morph targets: rest positions and per-target offsets.

    ``positions`` (vertices × 3) and every ``targets[name]`` (the same shape) are in the model's
    scene units (metres, for glTF), after the node transforms; ``name`` is the channel name
    (:data:`~vispeech.motion.arkit.MORPH_NAMES`).
    """

    positions: np.ndarray
    targets: dict[str, np.ndarray]


@dataclass(frozen=True)
class Primitive(MorphMesh):
    """A :class:`MorphMesh` with where it is in the file and what it is made of: ``mesh`` and
    ``index`` (the primitive's place in that mesh), ``name`` (its material's name, else its
    mesh's), ``triangles`` (faces × 3 vertex indices; empty for points and lines) and ``coloured``
    (whether it has vertex colours or a base-colour texture already)."""

    mesh: int
    index: int
    name: str
    triangles: np.ndarray
    coloured: bool

    @property
    def edges(self) -> np.ndarray:
        """The triangles' edges (3 per triangle, as vertex index pairs; shared edges repeated)."""
        t = self.triangles
        return np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])


def read_primitives(path: str | os.PathLike) -> list[Primitive]:
    """Every primitive of the meshes whose morph targets carry channel names, with quantized and
    meshopt-compressed data decoded, in the order of the file. Raises :class:`VispeechError` for a VRM
    model with none (one without "perfect sync")."""
    gltf = load_glb(path)
    if not animated_meshes(gltf) and {"VRM", "VRMC_vrm"} & set(gltf.extensions or {}):
        raise VispeechError(
            f"{path}: a VRM without ARKit morph targets (no perfect sync): the player shows it through its "
            "expressions (aa, ih, ou, ee, oh, blink, happy, sad); it has no ARKit lip and eyelid shapes to work on"
        )
    blob = decompressed(gltf, path)
    found = []
    for index, names in animated_meshes(gltf).items():
        nodes = [k for k, node in enumerate(gltf.nodes) if node.mesh == index]
        if not nodes:
            continue
        matrix = world_matrix(gltf, nodes[0])
        mesh = gltf.meshes[index]
        for k, primitive in enumerate(mesh.primitives):
            if not primitive.targets or len(primitive.targets) != len(names):
                continue
            base = _read_accessor(gltf, blob, primitive.attributes.POSITION, path)
            targets = {
                name: _read_accessor(gltf, blob, target["POSITION"], path) @ matrix[:3, :3].T
                for name, target in zip(names, primitive.targets)
                if name and "POSITION" in target
            }
            if primitive.mode in (None, 4):
                faces = (
                    _read_accessor(gltf, blob, primitive.indices, path)
                    if primitive.indices is not None
                    else np.arange(len(base), dtype=float)
                )
                triangles = faces.astype(np.int64).reshape(-1, 3)
            else:
                triangles = np.zeros((0, 3), dtype=np.int64)
            material = gltf.materials[primitive.material] if primitive.material is not None else None
            textured = (
                material is not None
                and material.pbrMetallicRoughness is not None
                and (material.pbrMetallicRoughness.baseColorTexture is not None)
            )
            found.append(
                Primitive(
                    base @ matrix[:3, :3].T + matrix[:3, 3],
                    targets,
                    index,
                    k,
                    (material.name if material else None) or mesh.name or f"mesh {index}",
                    triangles,
                    textured or primitive.attributes.COLOR_0 is not None,
                )
            )
    return found


def skin_primitive(primitives: list[Primitive], source: str | os.PathLike = "the head") -> Primitive:
    """The skin of a head: of its ``primitives``, the one the eyelids' ``eyeBlinkLeft`` moves furthest
    (the face, not teeth or tongue). Raises :class:`VispeechError` when none moves."""

    def reach(primitive: Primitive) -> float:
        blink = primitive.targets.get("eyeBlinkLeft")
        return float(np.linalg.norm(blink, axis=1).max()) if blink is not None and len(blink) else 0.0

    best = max(primitives, key=reach, default=None)
    if best is None or reach(best) <= 0:
        raise VispeechError(f"{source}: no mesh with ARKit morph targets that close the eyelids (eyeBlinkLeft)")
    return best


def read_morph_mesh(path: str | os.PathLike) -> MorphMesh:
    """The skin of a GLB head (:func:`skin_primitive`), with quantized and meshopt-compressed data
    decoded."""
    skin = skin_primitive(read_primitives(path), path)
    return MorphMesh(skin.positions, skin.targets)


def _read_accessor(gltf: pygltflib.GLTF2, blob: bytes, index: int, path: str | os.PathLike) -> np.ndarray:
    """An accessor's values as float64 (count × components), normalized integers scaled, sparse
    entries applied."""
    try:
        accessor = gltf.accessors[index]
        width = _WIDTHS[accessor.type]
        dtype = np.dtype(_COMPONENTS[accessor.componentType]).newbyteorder("<")
        out = np.zeros((accessor.count, width))
        if accessor.bufferView is not None:
            view = gltf.bufferViews[accessor.bufferView]
            stride = view.byteStride or dtype.itemsize * width
            start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
            rows = np.frombuffer(blob, np.uint8, count=stride * accessor.count, offset=start).reshape(-1, stride)
            out = rows[:, : dtype.itemsize * width].copy().view(dtype).astype(np.float64)
        if accessor.sparse is not None:
            sparse = accessor.sparse
            index_type = np.dtype(_COMPONENTS[sparse.indices.componentType]).newbyteorder("<")
            index_view = gltf.bufferViews[sparse.indices.bufferView]
            value_view = gltf.bufferViews[sparse.values.bufferView]
            rows_at = np.frombuffer(
                blob,
                index_type,
                count=sparse.count,
                offset=(index_view.byteOffset or 0) + (sparse.indices.byteOffset or 0),
            )
            values = np.frombuffer(
                blob,
                dtype,
                count=sparse.count * width,
                offset=(value_view.byteOffset or 0) + (sparse.values.byteOffset or 0),
            )
            out[rows_at.astype(np.intp)] = values.reshape(-1, width)
        if accessor.normalized and dtype.kind in "iu":
            # kind "i" or "u": an integer dtype, which the dict of component types does not tell the checker
            out = np.maximum(out / np.iinfo(cast("np.dtype[np.integer]", dtype)).max, -1.0)
        return out
    except (IndexError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise VispeechError(f"{path}: cannot read accessor {index} ({exc})") from None


_TURNED = np.diag([-1.0, 1.0, -1.0, 1.0])
"""Half a turn about +Y: a VRM 0.x model, which faces -Z, turned to face +Z as glTF heads do."""


def world_matrix(gltf: pygltflib.GLTF2, node_index: int) -> np.ndarray:
    """The 4x4 transform from node ``node_index``'s space to the scene's (its parents' included), a
    VRM 0.x model (the ``VRM`` extension) turned to face +Z as VRM 1.0 and glTF heads do."""
    parents = {child: k for k, node in enumerate(gltf.nodes) for child in (node.children or [])}
    matrix = np.eye(4)
    k: int | None = node_index
    while k is not None:
        matrix = _local_matrix(gltf.nodes[k]) @ matrix
        k = parents.get(k)
    return _TURNED @ matrix if "VRM" in (gltf.extensions or {}) else matrix


def _local_matrix(node: pygltflib.Node) -> np.ndarray:
    if node.matrix:
        return np.array(node.matrix, dtype=float).reshape(4, 4).T  # glTF matrices are column-major
    x, y, z, w = node.rotation or (0.0, 0.0, 0.0, 1.0)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * np.array(node.scale or (1.0, 1.0, 1.0))
    matrix[:3, 3] = node.translation or (0.0, 0.0, 0.0)
    return matrix


def load_glb(path: str | os.PathLike) -> pygltflib.GLTF2:
    """The glTF of the GLB file ``path``, its container checked first (:func:`_check_glb`)."""
    path = Path(path)
    data = read_bytes(path, "base model", MAX_GLB_BYTES)
    _check_glb(data, path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return pygltflib.GLTF2.load_from_bytes(data)
    except Exception as exc:  # pygltflib raises assorted exception types on malformed files
        detail = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise VispeechError(f"cannot load {path}: {detail}") from None


def embedded_glb(path: str | os.PathLike) -> pygltflib.GLTF2:
    """:func:`load_glb` of a model whose first buffer is its binary chunk, as the writers need it."""
    gltf = load_glb(path)
    if gltf.buffers and gltf.buffers[0].uri is not None:
        raise VispeechError(f"{path}: its first buffer is an external file; use a .glb with its data embedded")
    return gltf


def _check_glb(data: bytes, path: Path) -> None:
    """Check the GLB container against its size before anything parses it.

    The 12-byte header (magic, version 2, total length equal to the file's), each chunk's
    length within the file, a JSON chunk first and at most one BIN chunk after it, the JSON
    within the depth limits, and every embedded buffer's ``byteLength`` and buffer view's
    range within the bytes there are. Raises :class:`VispeechError` naming the byte offset.
    """
    if len(data) < 12 or data[:4] != b"glTF":
        raise VispeechError(f"{path} is not a binary glTF (.glb) file")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise VispeechError(f"{path}: GLB version {version}, only version 2 is read")
    if length != len(data):
        raise VispeechError(
            f"{path}: the GLB header (byte 8) declares {length} bytes but the file has {len(data)}"
            + (" (cut short?)" if length > len(data) else "")
        )
    chunks: list[tuple[bytes, int, int]] = []
    offset = 12
    while offset < length:
        if length - offset < 8:
            raise VispeechError(f"{path}, byte {offset}: {length - offset} bytes left, too few for a chunk header")
        size, kind = struct.unpack_from("<I4s", data, offset)
        if size > length - offset - 8:
            raise VispeechError(
                f"{path}, byte {offset}: chunk {len(chunks)} declares {size} bytes, only {length - offset - 8} remain"
            )
        chunks.append((kind, offset + 8, size))
        offset += 8 + size
    if not chunks or chunks[0][0] != b"JSON":
        raise VispeechError(f"{path}, byte 12: the first chunk must be JSON")
    if len(chunks) > 2 or (len(chunks) == 2 and chunks[1][0] != b"BIN\x00"):
        raise VispeechError(f"{path}, byte {chunks[1][1] - 8}: after the JSON chunk only one BIN chunk may follow")
    _, start, size = chunks[0]
    try:
        text = data[start : start + size].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise VispeechError(f"{path}, byte {start + exc.start}: the JSON chunk is not UTF-8") from None
    gltf = parse_json(text, f"{path} (JSON chunk)")
    if not isinstance(gltf, dict):
        raise VispeechError(f"{path}: the JSON chunk is not an object")
    binary = chunks[1][2] if len(chunks) == 2 else 0
    buffers = _list(gltf, "buffers", path)
    sizes = []
    for i, buffer in enumerate(buffers):
        byte_length = _count(buffer, "byteLength", f"buffers[{i}]", path) if isinstance(buffer, dict) else None
        if byte_length is None:
            raise VispeechError(f"{path}: buffers[{i}] needs a byteLength")
        if i == 0 and "uri" not in buffer and byte_length > binary:
            raise VispeechError(
                f"{path}: buffers[0].byteLength is {byte_length} but the BIN chunk holds {binary} bytes"
            )
        sizes.append(byte_length)
    for i, view in enumerate(_list(gltf, "bufferViews", path)):
        where = f"bufferViews[{i}]"
        if not isinstance(view, dict):
            raise VispeechError(f"{path}: {where} is not an object")
        buffer = _count(view, "buffer", where, path)
        view_start = _count(view, "byteOffset", where, path) or 0
        view_length = _count(view, "byteLength", where, path)
        if buffer is None or view_length is None or buffer >= len(sizes):
            raise VispeechError(f"{path}: {where} needs a buffer (of {len(sizes)}) and a byteLength")
        if view_start + view_length > sizes[buffer]:
            raise VispeechError(
                f"{path}: {where} runs to byte {view_start + view_length} of buffer {buffer}, which has {sizes[buffer]}"
            )


def _list(gltf: dict, key: str, path: Path) -> list:
    value = gltf.get(key, [])
    if not isinstance(value, list):
        raise VispeechError(f"{path}: '{key}' must be a list")
    return value


def _count(item: dict, key: str, where: str, path: Path) -> int | None:
    value = item.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise VispeechError(f"{path}: {where}.{key} must be a non-negative integer, got {value!r}")
    return value


def decompressed(gltf: pygltflib.GLTF2, path: str | os.PathLike) -> bytes:
    """The binary chunk with every ``EXT_meshopt_compression`` buffer view decoded in place
    (``gltf`` changed to match: one buffer, no fallback buffers, the extension dropped); the
    chunk as it is when nothing is compressed."""
    blob = gltf.binary_blob() or b""
    compressed = "EXT_meshopt_compression"
    if compressed not in (gltf.extensionsUsed or []):
        return blob
    import meshopt

    out = bytearray()
    try:
        for view in gltf.bufferViews:
            ext = (view.extensions or {}).get(compressed)
            if ext is not None:
                if ext["buffer"] != 0:
                    raise VispeechError(f"{path}: compressed data outside the binary chunk")
                size = int(ext["count"]) * int(ext["byteStride"])
                if not 0 <= size <= MAX_GLB_BYTES - len(out):
                    raise VispeechError(
                        f"{path}: its meshopt-compressed data would decode to more than {MAX_GLB_BYTES // 2**20} MiB"
                    )
                source = blob[ext["byteOffset"] : ext["byteOffset"] + ext["byteLength"]]
                data = meshopt.decode_gltf_buffer(
                    source, ext["count"], ext["byteStride"], ext["mode"], ext.get("filter")
                ).tobytes()
                view.extensions = {k: v for k, v in view.extensions.items() if k != compressed}
            elif view.buffer == 0:
                data = blob[(view.byteOffset or 0) : (view.byteOffset or 0) + view.byteLength]
            else:
                raise VispeechError(f"{path}: an uncompressed buffer view outside the binary chunk")
            out.extend(b"\x00" * (-len(out) % 4))
            view.buffer, view.byteOffset, view.byteLength = 0, len(out), len(data)
            out.extend(data)
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise VispeechError(f"{path}: cannot decode its meshopt-compressed data ({exc})") from None
    out.extend(b"\x00" * (-len(out) % 4))
    gltf.buffers = [pygltflib.Buffer(byteLength=len(out))]
    gltf.extensionsUsed = [e for e in gltf.extensionsUsed if e != compressed]
    gltf.extensionsRequired = [e for e in (gltf.extensionsRequired or []) if e != compressed]
    return bytes(out)


def glb_bytes(gltf: pygltflib.GLTF2, blob: bytearray) -> bytes:
    """The GLB container: header, JSON chunk (space-padded), BIN chunk ``blob`` (padded to 4
    bytes, and buffer 0's length set to it).

    Written here rather than by pygltflib's ``save_binary``, which repacks every buffer view
    into one buffer and so breaks EXT_meshopt_compression's fallback buffers. An accessor
    without a buffer view (all zeros) is written without the ``byteOffset`` 0 that pygltflib
    gives every accessor: glTF allows that field only with a buffer view.
    """
    for accessor in gltf.accessors:
        if accessor.bufferView is None:
            accessor.byteOffset = None
    blob.extend(b"\x00" * (-len(blob) % 4))
    if not gltf.buffers:
        gltf.buffers.append(pygltflib.Buffer(byteLength=0))
    gltf.buffers[0].byteLength = len(blob)
    text = gltf.gltf_to_json(separators=(",", ":"), indent=None).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\x00") + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def animated_meshes(gltf: pygltflib.GLTF2) -> dict[int, list[str | None]]:
    """Mesh index -> channel name (or None) of each morph target, for meshes with any named channel target."""
    found = {}
    for index, mesh in enumerate(gltf.meshes):
        if not mesh.primitives or not mesh.primitives[0].targets:
            continue
        names = (mesh.extras or {}).get("targetNames") or (mesh.primitives[0].extras or {}).get("targetNames")
        if not isinstance(names, list) or len(names) != len(mesh.primitives[0].targets):
            continue
        channels = [target_channel(str(n)) for n in names]
        if any(channels):
            found[index] = channels
    return found


def append_accessor(gltf: pygltflib.GLTF2, blob: bytearray, data: np.ndarray) -> int:
    """Append float32 data (a vector of scalars, or rows of 2-4 components) as a new buffer view and
    accessor in buffer 0; return the accessor index."""
    data = np.asarray(data, dtype=np.float32)
    rows = data.reshape(len(data), -1)
    blob.extend(b"\x00" * (-len(blob) % 4))
    raw = np.ascontiguousarray(rows, dtype="<f4").tobytes()
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
    blob.extend(raw)
    kind = "SCALAR" if data.ndim == 1 else f"VEC{rows.shape[1]}"
    gltf.accessors.append(
        pygltflib.Accessor(
            bufferView=len(gltf.bufferViews) - 1,
            componentType=FLOAT,
            count=len(rows),
            type=kind,
            min=[float(v) for v in rows.min(axis=0)],
            max=[float(v) for v in rows.max(axis=0)],
        )
    )
    return len(gltf.accessors) - 1
