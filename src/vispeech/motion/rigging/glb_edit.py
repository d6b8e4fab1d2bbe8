"""A copy of a GLB head with additions: morph targets, vertex colours, rest positions and new
primitives (:func:`extended_glb`), what :func:`vispeech.motion.rigging.head.prepared_head`
writes. The existing binary data is kept byte for byte (compressed data stays compressed); the
new data is appended uncompressed, morph targets that move few vertices of a new primitive as
sparse accessors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pygltflib

from vispeech.errors import VispeechError
from vispeech.motion.rigging.glb import FLOAT, animated_meshes, append_accessor, embedded_glb, glb_bytes, world_matrix

MOVES = 0.001
"""Metres a morph target must move some vertex of a new primitive by to be stored on it."""


@dataclass(frozen=True)
class NewPrimitive:
    """A primitive to add to a mesh: ``positions`` and ``normals`` (vertices × 3, scene units, as
    :func:`read_primitives` gives them), ``triangles`` (faces × 3), ``colours`` (``COLOR_0``,
    vertices × 4, linear RGBA), the offsets of the morph targets that move it (by channel name;
    the mesh's others leave it still, as do targets that move none of its vertices by
    :data:`MOVES` or more; offsets under 20 µm are dropped, and a target that moves few of its
    vertices is stored sparse), and its material: ``name``, ``base_colour`` (linear
    RGBA), ``roughness``, ``alpha_cutoff`` (alpha mode MASK when set), ``double_sided``, and a
    base colour ``texture`` (PNG bytes, repeated) on the texture coordinates ``uvs`` (vertices × 2)."""

    name: str
    positions: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray
    colours: np.ndarray
    targets: dict[str, np.ndarray]
    base_colour: tuple[float, float, float, float]
    roughness: float
    alpha_cutoff: float | None = None
    double_sided: bool = False
    uvs: np.ndarray | None = None
    texture: bytes | None = None


def extended_glb(
    base_glb: str | os.PathLike,
    *,
    targets: dict[tuple[int, int], dict[str, np.ndarray]] | None = None,
    attributes: dict[tuple[int, int], dict[str, np.ndarray]] | None = None,
    positions: dict[tuple[int, int], np.ndarray] | None = None,
    added: dict[int, list[NewPrimitive]] | None = None,
    extensions: dict[tuple[int, int], dict[str, dict]] | None = None,
) -> bytes:
    """The bytes of a copy of ``base_glb`` with morph targets, vertex colours, rest positions and
    primitives added to its meshes.

    ``targets[(mesh, primitive)][name]``: a new morph target's offsets (vertices × 3, scene units,
    as :func:`~vispeech.motion.rigging.glb.read_primitives` gives them); every other primitive
    of that mesh gets the same target with no offsets (an accessor without data, zeros by the
    glTF rules), and the name is appended to ``mesh.extras.targetNames``; a target that moves
    few vertices is stored sparse. ``attributes[(mesh, primitive)][name]``: a vertex attribute
    (values 0..1, one row per vertex) in place of the primitive's, such as ``COLOR_0`` (vertices
    × 3, linear RGB, multiplying the material's base colour; stored as bytes) or an
    application's own (``_OCCLUSION``). ``positions[(mesh, primitive)]``: new rest positions
    (vertices × 3, scene units) in place of the primitive's. ``added[mesh]``: primitives
    appended to that mesh, each with its own material (:class:`NewPrimitive`).
    ``extensions[(mesh, primitive)][name]``: a material extension (``KHR_materials_sheen``) set
    on the primitive's material and listed as used.
    Compressed data stays compressed; the new data is appended uncompressed.
    """
    gltf = embedded_glb(base_glb)
    blob = bytearray(gltf.binary_blob() or b"")
    _add_targets(gltf, blob, targets or {}, base_glb)
    for (mesh, primitive), named in (attributes or {}).items():
        for name, values in named.items():
            values = np.clip(np.asarray(values, float), 0.0, 1.0)
            accessor = _append_colours(gltf, blob, values) if name == "COLOR_0" else append_accessor(gltf, blob, values)
            setattr(gltf.meshes[mesh].primitives[primitive].attributes, name, accessor)
    for (mesh, primitive), moved in (positions or {}).items():
        to_local = np.linalg.inv(_mesh_matrix(gltf, mesh))
        local = np.asarray(moved, float) @ to_local[:3, :3].T + to_local[:3, 3]
        gltf.meshes[mesh].primitives[primitive].attributes.POSITION = append_accessor(gltf, blob, local)
    for mesh, primitives in (added or {}).items():
        for new in primitives:
            _add_primitive(gltf, blob, mesh, new)
    for (mesh, primitive), extension in (extensions or {}).items():
        material = gltf.materials[gltf.meshes[mesh].primitives[primitive].material]
        material.extensions = {**(material.extensions or {}), **extension}
        gltf.extensionsUsed = [*dict.fromkeys([*(gltf.extensionsUsed or []), *extension])]
    return glb_bytes(gltf, blob)


def _mesh_matrix(gltf: pygltflib.GLTF2, mesh: int) -> np.ndarray:
    """The world matrix of the first node that shows ``mesh``."""
    return world_matrix(gltf, next(k for k, node in enumerate(gltf.nodes) if node.mesh == mesh))


def _add_targets(
    gltf: pygltflib.GLTF2, blob: bytearray, targets: dict[tuple[int, int], dict[str, np.ndarray]], source
) -> None:
    """Append the new morph targets of :func:`extended_glb` to ``gltf``."""
    names_of = animated_meshes(gltf)
    by_mesh: dict[int, dict[int, dict[str, np.ndarray]]] = {}
    for (mesh, primitive), offsets in (targets or {}).items():
        by_mesh.setdefault(mesh, {})[primitive] = offsets
    for mesh, per_primitive in by_mesh.items():
        names = [n for offsets in per_primitive.values() for n in offsets]
        new = list(dict.fromkeys(names))
        clash = [n for n in new if n in names_of.get(mesh, [])]
        if clash:
            raise VispeechError(f"{source}: mesh {mesh} already has a morph target {clash[0]!r}")
        to_local = np.linalg.inv(_mesh_matrix(gltf, mesh)[:3, :3])
        for k, primitive in enumerate(gltf.meshes[mesh].primitives):
            count = gltf.accessors[primitive.attributes.POSITION].count
            for name in new:
                moved = per_primitive.get(k, {}).get(name)
                local = np.zeros((0, 3)) if moved is None else np.asarray(moved, float) @ to_local.T
                rows = np.flatnonzero(np.abs(local).max(axis=1) > 0) if len(local) else np.zeros(0, int)
                primitive.targets.append({"POSITION": _append_sparse(gltf, blob, count, rows, local[rows])})
        extras = gltf.meshes[mesh].extras if gltf.meshes[mesh].extras else {}
        extras["targetNames"] = [*extras.get("targetNames", []), *new]
        gltf.meshes[mesh].extras = extras
        if gltf.meshes[mesh].weights:
            gltf.meshes[mesh].weights = [*gltf.meshes[mesh].weights, *[0.0] * len(new)]


def _add_primitive(gltf: pygltflib.GLTF2, blob: bytearray, mesh: int, new: NewPrimitive) -> None:
    """Append ``new`` (and its material) to mesh ``mesh`` of ``gltf``, with a morph target for each of the mesh's."""
    to_local = np.linalg.inv(_mesh_matrix(gltf, mesh))
    linear = to_local[:3, :3]
    count = len(new.positions)
    names = animated_meshes(gltf).get(mesh, [])
    morphs = []
    for name in names:
        offsets = new.targets.get(name) if name else None
        reach = np.linalg.norm(offsets, axis=1) if offsets is not None else np.zeros(count)
        moving = np.flatnonzero(reach > 5e-5) if reach.max() >= MOVES else np.zeros(0, int)
        local = np.asarray(offsets, float)[moving] @ linear.T if len(moving) else np.zeros((0, 3))
        morphs.append({"POSITION": _append_sparse(gltf, blob, count, moving, local)})
    normals = np.asarray(new.normals, float) @ np.linalg.inv(linear)
    texture = None
    if new.texture is not None:
        blob.extend(b"\x00" * (-len(blob) % 4))
        gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(new.texture)))
        blob.extend(new.texture)
        gltf.images.append(pygltflib.Image(bufferView=len(gltf.bufferViews) - 1, mimeType="image/png"))
        gltf.samplers.append(pygltflib.Sampler(magFilter=9729, minFilter=9987, wrapS=10497, wrapT=33071))
        gltf.textures.append(pygltflib.Texture(source=len(gltf.images) - 1, sampler=len(gltf.samplers) - 1))
        texture = pygltflib.TextureInfo(index=len(gltf.textures) - 1)
    gltf.materials.append(
        pygltflib.Material(
            name=new.name,
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=list(new.base_colour),
                metallicFactor=0.0,
                roughnessFactor=new.roughness,
                baseColorTexture=texture,
            ),
            alphaMode="MASK" if new.alpha_cutoff is not None else "OPAQUE",
            alphaCutoff=new.alpha_cutoff,
            doubleSided=new.double_sided,
        )
    )
    gltf.meshes[mesh].primitives.append(
        pygltflib.Primitive(
            attributes=pygltflib.Attributes(
                POSITION=append_accessor(gltf, blob, np.asarray(new.positions, float) @ linear.T + to_local[:3, 3]),
                NORMAL=append_accessor(gltf, blob, normals / np.linalg.norm(normals, axis=1, keepdims=True)),
                COLOR_0=_append_colours(gltf, blob, np.clip(np.asarray(new.colours, float), 0.0, 1.0)),
                TEXCOORD_0=None if new.uvs is None else append_accessor(gltf, blob, np.asarray(new.uvs, float)),
            ),
            indices=_append_indices(gltf, blob, np.asarray(new.triangles)),
            material=len(gltf.materials) - 1,
            targets=morphs,
        )
    )


def _append_colours(gltf: pygltflib.GLTF2, blob: bytearray, colours: np.ndarray) -> int:
    """Append colours (vertices × 3 or 4, 0..1) as normalized unsigned bytes, RGBA (alpha 1 for RGB); the
    accessor's index."""
    rgba = np.column_stack([colours, np.ones(len(colours))]) if colours.shape[1] == 3 else colours
    blob.extend(b"\x00" * (-len(blob) % 4))
    raw = np.ascontiguousarray(np.round(rgba * 255), dtype=np.uint8).tobytes()
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
    blob.extend(raw)
    gltf.accessors.append(
        pygltflib.Accessor(
            bufferView=len(gltf.bufferViews) - 1, componentType=5121, normalized=True, count=len(rgba), type="VEC4"
        )
    )
    return len(gltf.accessors) - 1


def _append_indices(gltf: pygltflib.GLTF2, blob: bytearray, triangles: np.ndarray) -> int:
    """Append triangle indices (unsigned 16-bit, or 32-bit for over 65535 vertices) as a new buffer view and
    accessor; the accessor's index."""
    wide = triangles.max(initial=0) > 65535
    blob.extend(b"\x00" * (-len(blob) % 4))
    raw = np.ascontiguousarray(triangles.reshape(-1), dtype="<u4" if wide else "<u2").tobytes()
    gltf.bufferViews.append(
        pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw), target=pygltflib.ELEMENT_ARRAY_BUFFER)
    )
    blob.extend(raw)
    gltf.accessors.append(
        pygltflib.Accessor(
            bufferView=len(gltf.bufferViews) - 1,
            componentType=5125 if wide else 5123,
            count=triangles.size,
            type="SCALAR",
        )
    )
    return len(gltf.accessors) - 1


def _append_sparse(gltf: pygltflib.GLTF2, blob: bytearray, count: int, rows: np.ndarray, values: np.ndarray) -> int:
    """A VEC3 accessor of ``count`` zeros but ``values`` at ``rows``: without data when none move, sparse when
    that is smaller (under three quarters move), else dense; its index."""
    if not len(rows):
        gltf.accessors.append(
            pygltflib.Accessor(componentType=FLOAT, count=count, type="VEC3", min=[0.0] * 3, max=[0.0] * 3)
        )
        return len(gltf.accessors) - 1
    if 4 * len(rows) >= 3 * count:
        dense = np.zeros((count, 3))
        dense[rows] = values
        return append_accessor(gltf, blob, dense)
    blob.extend(b"\x00" * (-len(blob) % 4))
    index_raw = np.ascontiguousarray(rows, dtype="<u4").tobytes()
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(index_raw)))
    blob.extend(index_raw)
    value_raw = np.ascontiguousarray(values, dtype="<f4").tobytes()
    gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(value_raw)))
    blob.extend(value_raw)
    low, high = np.minimum(values.min(axis=0), 0.0), np.maximum(values.max(axis=0), 0.0)
    gltf.accessors.append(
        pygltflib.Accessor(
            componentType=FLOAT,
            count=count,
            type="VEC3",
            min=[float(v) for v in low],
            max=[float(v) for v in high],
            sparse=pygltflib.Sparse(
                count=len(rows),
                indices=pygltflib.AccessorSparseIndices(bufferView=len(gltf.bufferViews) - 2, componentType=5125),
                values=pygltflib.AccessorSparseValues(bufferView=len(gltf.bufferViews) - 1),
            ),
        )
    )
    return len(gltf.accessors) - 1
