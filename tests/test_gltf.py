"""glTF export: a weights animation appended to a GLB, checked by reading the file back."""

import numpy as np
import pygltflib
import pytest

from vispeech import Track, VispeechError
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.motion.rigging.glb import target_channel


def accessor_data(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    start = view.byteOffset + (accessor.byteOffset or 0)
    assert accessor.componentType == pygltflib.FLOAT and accessor.type == "SCALAR" and view.buffer == 0
    return np.frombuffer(gltf.binary_blob()[start:start + 4 * accessor.count], dtype="<f4")


def speech_track(n=45, fps=30.0) -> Track:
    rng = np.random.default_rng(7)
    return Track(rng.uniform(0, 1, (n, len(ARKIT_NAMES))), ARKIT_NAMES, fps, start_time=2.0)


def tiny_glb(path, target_names, n_nodes=2):
    """One triangle with a morph target per name, used by ``n_nodes`` nodes, plus a plain mesh."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")
    blob = positions.tobytes() * (1 + len(target_names))
    views = [pygltflib.BufferView(buffer=0, byteOffset=36 * i, byteLength=36) for i in range(1 + len(target_names))]
    accessors = [pygltflib.Accessor(bufferView=i, componentType=pygltflib.FLOAT, count=3, type="VEC3",
                                    min=[0, 0, 0], max=[1, 1, 0]) for i in range(len(views))]
    morph = pygltflib.Mesh(primitives=[pygltflib.Primitive(
        attributes=pygltflib.Attributes(POSITION=0),
        targets=[{"POSITION": i + 1} for i in range(len(target_names))])], extras={"targetNames": target_names})
    plain = pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0))])
    nodes = [pygltflib.Node(mesh=0) for _ in range(n_nodes)] + [pygltflib.Node(mesh=1)]
    gltf = pygltflib.GLTF2(scene=0, scenes=[pygltflib.Scene(nodes=list(range(len(nodes))))], nodes=nodes,
                           meshes=[morph, plain], accessors=accessors, bufferViews=views,
                           buffers=[pygltflib.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(blob)
    gltf.save_binary(str(path))


@pytest.mark.parametrize("name,arkit", [
    ("jawOpen", "jawOpen"), ("JAWOPEN", "jawOpen"), ("blendShape1.mouthClose", "mouthClose"),
    ("eyeBlink_L", "eyeBlinkLeft"), ("mouthSmile_R", "mouthSmileRight"), ("Basis", None), ("viseme_aa", None),
    ("tongueTipUp", "tongueTipUp"), ("Tongue_Back", None),
])
def test_target_names(name, arkit):
    assert target_channel(name) == arkit


def test_ict_head_animation(tmp_path, shared_dir):
    base = shared_dir / "assets/ict_head.glb"
    track = speech_track()
    write_gltf_animation(track, base, tmp_path / "head.glb")
    original = pygltflib.GLTF2().load(str(base))
    gltf = pygltflib.GLTF2().load(str(tmp_path / "head.glb"))
    # The meshopt-compressed views are decoded into one plain buffer (importers without the
    # extension, Blender's among them, open it); the quantization stays.
    assert "EXT_meshopt_compression" in original.extensionsRequired
    assert gltf.extensionsUsed == gltf.extensionsRequired == ["KHR_mesh_quantization"]
    assert len(gltf.buffers) == 1 and gltf.buffers[0].byteLength == len(gltf.binary_blob())
    assert len(gltf.accessors) == len(original.accessors) + 2
    blob = gltf.binary_blob()
    for view, before in zip(gltf.bufferViews, original.bufferViews):
        ext = before.extensions["EXT_meshopt_compression"]
        assert not view.extensions and view.buffer == 0 and view.byteLength == ext["count"] * ext["byteStride"]
    primitive = gltf.meshes[0].primitives[0]
    for accessor_index in (primitive.attributes.POSITION, primitive.targets[0]["POSITION"]):
        accessor = gltf.accessors[accessor_index]
        view = gltf.bufferViews[accessor.bufferView]
        dtype = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5126: "<f4"}[accessor.componentType]
        rows = np.frombuffer(blob, np.uint8, accessor.count * view.byteStride,
                             view.byteOffset + (accessor.byteOffset or 0)).reshape(accessor.count, view.byteStride)
        size = np.dtype(dtype).itemsize
        values = rows[:, :3 * size].copy().view(dtype).reshape(accessor.count, 3)
        assert values.min(axis=0).tolist() == accessor.min and values.max(axis=0).tolist() == accessor.max

    (animation,) = gltf.animations
    assert animation.name == "speech"
    morph_nodes = [i for i, node in enumerate(gltf.nodes) if node.mesh is not None]
    assert [c.target.node for c in animation.channels] == morph_nodes
    assert all(c.target.path == "weights" for c in animation.channels)
    sampler = animation.samplers[animation.channels[0].sampler]
    assert sampler.interpolation == "LINEAR"

    times = accessor_data(gltf, sampler.input)
    assert np.allclose(times, np.arange(45) / 30.0)
    assert gltf.accessors[sampler.input].min == [0.0] and gltf.accessors[sampler.input].max == [float(times[-1])]
    names = gltf.meshes[0].extras["targetNames"]
    weights = accessor_data(gltf, sampler.output).reshape(45, len(names))
    assert gltf.accessors[sampler.output].count == 45 * 51
    assert gltf.accessors[sampler.output].min == [float(weights.min())]
    assert gltf.accessors[sampler.output].max == [float(weights.max())]
    assert np.allclose(weights[:, names.index("jawOpen")], track["jawOpen"], atol=1e-7)
    assert np.allclose(weights[:, names.index("mouthSmileLeft")], track["mouthSmileLeft"], atol=1e-7)


def test_suffixed_names_several_nodes_and_unmatched_targets(tmp_path):
    tiny_glb(tmp_path / "base.glb", ["blendShape1.jawOpen", "eyeBlink_L", "Wrinkle", "tongueOut"])
    track = Track(np.array([[0.0, 0.5], [0.25, 1.0], [1.0, 0.0]]), ("jawOpen", "eyeBlinkLeft"), 10.0)
    write_gltf_animation(track, tmp_path / "base.glb", tmp_path / "out.glb", name="talk")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "out.glb"))
    (animation,) = gltf.animations
    assert animation.name == "talk" and [c.target.node for c in animation.channels] == [0, 1]
    outputs = {animation.samplers[c.sampler].output for c in animation.channels}
    assert len(outputs) == 1  # both nodes share one mesh, hence one weights accessor
    weights = accessor_data(gltf, outputs.pop()).reshape(3, 4)
    assert np.allclose(weights, [[0.0, 0.5, 0, 0], [0.25, 1.0, 0, 0], [1.0, 0.0, 0, 0]])
    assert np.allclose(accessor_data(gltf, animation.samplers[0].input), [0.0, 0.1, 0.2])


def test_model_without_arkit_targets(tmp_path):
    tiny_glb(tmp_path / "base.glb", ["Smile", "Frown"])
    with pytest.raises(VispeechError, match="no mesh with ARKit-named morph targets"):
        write_gltf_animation(speech_track(), tmp_path / "base.glb", tmp_path / "out.glb")
    assert not (tmp_path / "out.glb").exists()


def test_bad_base_files(tmp_path):
    with pytest.raises(VispeechError, match="base model not found"):
        write_gltf_animation(speech_track(), tmp_path / "none.glb", tmp_path / "out.glb")
    (tmp_path / "text.glb").write_text("{}")
    with pytest.raises(VispeechError, match="not a binary glTF"):
        write_gltf_animation(speech_track(), tmp_path / "text.glb", tmp_path / "out.glb")


def test_meshopt_data_that_would_decode_too_large_is_refused(tmp_path, shared_dir):
    import json
    import struct

    data = (shared_dir / "assets/ict_head.glb").read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + length])
    gltf["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["count"] = 10**12
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + length:]
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + rest
    (tmp_path / "huge.glb").write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    with pytest.raises(VispeechError, match="would decode to more than 512 MiB"):
        write_gltf_animation(speech_track(), tmp_path / "huge.glb", tmp_path / "out.glb")
    assert not (tmp_path / "out.glb").exists()
