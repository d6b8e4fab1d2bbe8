"""glTF export: a weights animation appended to a GLB, checked by reading the file back."""

import json
import struct

import numpy as np
import pygltflib
import pytest

from vispeech import Track, VispeechError
from vispeech.errors import UnshownChannelsWarning
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.motion.rigging.glb import load_glb, read_primitives, target_channel


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


def check_animation(gltf: pygltflib.GLTF2, track: Track) -> None:
    """``gltf`` holds ``track`` as one LINEAR weights animation of every node with morph targets."""
    (animation,) = gltf.animations
    assert animation.name == "speech"
    morph_nodes = [i for i, node in enumerate(gltf.nodes) if node.mesh is not None]
    assert [c.target.node for c in animation.channels] == morph_nodes
    assert all(c.target.path == "weights" for c in animation.channels)
    sampler = animation.samplers[animation.channels[0].sampler]
    assert sampler.interpolation == "LINEAR"

    times = accessor_data(gltf, sampler.input)
    assert np.allclose(times, np.arange(track.n_frames) / track.fps)
    assert gltf.accessors[sampler.input].min == [0.0] and gltf.accessors[sampler.input].max == [float(times[-1])]
    names = gltf.meshes[0].extras["targetNames"]
    weights = accessor_data(gltf, sampler.output).reshape(track.n_frames, len(names))
    assert gltf.accessors[sampler.output].count == track.n_frames * len(names)
    assert gltf.accessors[sampler.output].min == [float(weights.min())]
    assert gltf.accessors[sampler.output].max == [float(weights.max())]
    for j, name in enumerate(names):
        assert np.allclose(weights[:, j], track[name] if name in track.channels else 0.0, atol=1e-7), name


def test_ict_head_animation_keeps_the_compression(tmp_path, shared_dir):
    """The meshopt-compressed head stays compressed byte for byte; the animation is appended."""
    base = shared_dir / "assets/ict_head.glb"
    track = speech_track()
    with pytest.warns(UnshownChannelsWarning) as caught:
        write_gltf_animation(track, base, tmp_path / "head.glb")
    assert len(caught) == 1 and str(caught[0].message).endswith("the track's channels, which are left out: tongueOut")
    original = load_glb(base)
    gltf = load_glb(tmp_path / "head.glb")  # the project's reader: its container checks pass
    assert gltf.extensionsUsed == original.extensionsUsed and "EXT_meshopt_compression" in gltf.extensionsRequired
    assert gltf.buffers[1:] == original.buffers[1:]  # the fallback buffer of the compressed views
    assert gltf.bufferViews[:len(original.bufferViews)] == original.bufferViews
    assert gltf.binary_blob().startswith(original.binary_blob())
    assert len(gltf.accessors) == len(original.accessors) + 2
    animation_bytes = 4 * track.n_frames * (1 + 51)
    size = (tmp_path / "head.glb").stat().st_size  # the JSON, rewritten by pygltflib, grows by 10 KB
    assert base.stat().st_size + animation_bytes < size < base.stat().st_size + animation_bytes + 32 * 1024
    check_animation(gltf, track)
    before, after = read_primitives(base), read_primitives(tmp_path / "head.glb")  # decoded from the copy
    assert len(after) == len(before)
    for old, new in zip(before, after):
        assert np.array_equal(new.positions, old.positions) and np.array_equal(new.triangles, old.triangles)
        assert new.targets.keys() == old.targets.keys()
        assert all(np.array_equal(new.targets[k], old.targets[k]) for k in old.targets)


def test_ict_head_animation_uncompressed(tmp_path, shared_dir):
    base = shared_dir / "assets/ict_head.glb"
    track = speech_track()
    with pytest.warns(UnshownChannelsWarning, match="tongueOut"):
        write_gltf_animation(track, base, tmp_path / "head.glb", uncompressed=True)
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
    check_animation(gltf, track)


def test_the_shipped_head_shows_every_channel_of_a_spoken_track(tmp_path, recwarn):
    """The shipped head (tongue targets added) takes a spoken track's 30 channels with no warning,
    in about its own size: 1.9 MB for 2.5 s, where decoding its compression made 12.9 MB."""
    from vispeech.motion.rigging.head import DEFAULT_HEAD
    from vispeech.pipeline import speak

    track = speak("The quick brown fox jumps over it.", "en").track
    write_gltf_animation(track, DEFAULT_HEAD, tmp_path / "head.glb")
    assert not [w for w in recwarn if w.category is UnshownChannelsWarning]
    gltf = load_glb(tmp_path / "head.glb")
    assert set(track.channels) <= set(gltf.meshes[0].extras["targetNames"])
    check_animation(gltf, track)
    data = (tmp_path / "head.glb").read_bytes()
    accessors = json.loads(data[20:20 + struct.unpack_from("<I", data, 12)[0]])["accessors"]
    zeros = [a for a in accessors if "bufferView" not in a]  # the data-less targets rig prepare adds
    assert zeros and not [a for a in zeros if "byteOffset" in a]  # glTF allows byteOffset only with a bufferView
    assert (tmp_path / "head.glb").stat().st_size < DEFAULT_HEAD.stat().st_size + 256 * track.n_frames


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
        write_gltf_animation(speech_track(), tmp_path / "huge.glb", tmp_path / "out.glb", uncompressed=True)
    assert not (tmp_path / "out.glb").exists()
