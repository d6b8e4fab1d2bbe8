"""A head made ready for vispeech (``vispeech rig prepare``): tongue morph targets from the ICT
head's own tongue geometry, painted looks, and the file they are written to."""

from __future__ import annotations

import numpy as np
import pygltflib
import pytest
from click.testing import CliRunner

from conftest import SHARED, require
from vispeech import VispeechError
from vispeech.cli import main
from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.motion.rigging.glb import read_primitives, skin_primitive
from vispeech.motion.rigging.head import DEFAULT_HEAD, prepare_head
from vispeech.motion.rigging.tongue import find_tongue


ICT_HEAD = SHARED / "assets" / "ict_head.glb"


@pytest.fixture(scope="module")
def ict_head():
    require(ICT_HEAD.is_file(), f"the ICT head ({ICT_HEAD}, in the shared data folder)")
    return ICT_HEAD


@pytest.fixture(scope="module")
def prepared(ict_head, tmp_path_factory):
    out = tmp_path_factory.mktemp("head") / "ict_ready.glb"
    report = prepare_head(ict_head, out)
    return out, report, read_primitives(out)


def by_name(primitives, name):
    return next(p for p in primitives if p.name == name)


def test_the_tongue_is_told_from_gums_palate_and_throat(ict_head):
    primitives = read_primitives(ict_head)
    tongue = find_tongue(primitives, ict_head)
    assert tongue.primitive.name == "M_GumsTongue"
    pos, w = tongue.primitive.positions, tongue.weights
    teeth = tongue.teeth.positions
    # the core sits between the lower teeth, behind the incisors, below the upper teeth
    core = pos[tongue.core]
    assert 300 < len(core) < len(pos) / 2
    assert core[:, 2].max() < teeth[:, 2].max() and np.abs(np.median(core[:, 0])) < 1e-3
    # the gums hug the teeth: nothing within 2.5 mm of a tooth is tongue
    from scipy.spatial import cKDTree

    near_teeth = cKDTree(teeth).query(pos)[0] < 0.0025
    assert near_teeth.sum() > 500 and np.all(w[near_teeth] == 0)
    # the palate and the throat do not move with the jaw and are not tongue
    assert tongue.fixed.sum() > 300 and np.all(w[tongue.fixed] == 0)


def test_prepared_head_has_tongue_targets_that_move_only_the_tongue(prepared, ict_head):
    out, report, primitives = prepared
    assert report.targets == list(TONGUE_CHANNELS)  # the ICT head has none of them, not even tongueOut
    tongue = find_tongue(read_primitives(ict_head), ict_head)
    gums = by_name(primitives, "M_GumsTongue")
    for primitive in primitives:
        assert set(TONGUE_CHANNELS) <= set(primitive.targets)
        if primitive is not gums:
            assert all(not np.any(primitive.targets[name]) for name in TONGUE_CHANNELS), primitive.name
    for name in TONGUE_CHANNELS:
        assert not np.any(gums.targets[name][tongue.weights == 0]), name  # gums, palate, throat stay
    pos, core = gums.positions, tongue.core
    tip = core[pos[core, 2] > pos[core, 2].max() - 0.005]
    middle = core[np.abs(pos[core, 2] - np.percentile(pos[core, 2], 35)) < 0.004]
    up, body = gums.targets["tongueTipUp"][:, 1], gums.targets["tongueBodyUp"][:, 1]
    assert up[tip].mean() > 0.008 and up[tip].mean() > 3 * up[middle].mean()  # the tip rises, not the body
    assert body[middle].mean() > 0.008 and body[middle].mean() > 3 * body[tip].mean()
    assert np.all(gums.targets["tongueBack"][core, 2] <= 0) and gums.targets["tongueBack"][tip, 2].mean() < -0.004
    out_z = pos[tip, 2] + gums.targets["tongueOut"][tip, 2]
    teeth = by_name(primitives, "M_Teeth").positions
    assert out_z.max() > teeth[:, 2].max()  # out past the front teeth


def test_raised_tongue_stays_below_the_roof(prepared, ict_head):
    """At full tongueTipUp or tongueBodyUp (jaw closed) the midline of the tongue stays under the
    palate and upper teeth above it."""
    _, _, primitives = prepared
    tongue = find_tongue(read_primitives(ict_head), ict_head)
    gums = by_name(primitives, "M_GumsTongue")
    teeth = by_name(primitives, "M_Teeth")
    roof = np.concatenate([gums.positions[tongue.fixed], teeth.positions[tongue.fixed_teeth]])
    roof = roof[np.abs(roof[:, 0]) < 0.004]
    core = tongue.core[np.abs(gums.positions[tongue.core, 0]) < 0.004]
    for name in ("tongueTipUp", "tongueBodyUp"):
        raised = gums.positions[core] + gums.targets[name][core]
        for point, rest in zip(raised, gums.positions[core]):
            above = roof[(np.abs(roof[:, 2] - rest[2]) < 0.002) & (roof[:, 1] > rest[1])]
            if len(above):
                assert point[1] <= above[:, 1].min() + 1e-6, (name, rest, point)


def test_paint(prepared):
    _, report, primitives = prepared
    assert report.painted == ["M_Face", "M_GumsTongue", "M_Teeth", "M_BackHead"]
    skin = skin_primitive(primitives)
    gltf = pygltflib.GLTF2.load(str(prepared[0]))
    coloured = {gltf.materials[p.material].name for p in gltf.meshes[0].primitives if p.attributes.COLOR_0 is not None}
    assert coloured == {"M_Face", "M_BackHead", "M_GumsTongue", "M_Teeth", "M_IrisLeft", "M_IrisRight",
                        "vispeech_hair", "vispeech_eyelashes"}
    face = _attribute(prepared[0], "M_Face", "COLOR_0")[:, :3]
    pos = skin.positions
    lips = (np.abs(pos[:, 0]) < 0.01) & (np.abs(pos[:, 1] + 0.034) < 0.006) & (pos[:, 2] > 0.1)
    cheeks = (np.abs(np.abs(pos[:, 0]) - 0.045) < 0.005) & (np.abs(pos[:, 1] + 0.01) < 0.005)
    brows = (np.abs(np.abs(pos[:, 0]) - 0.03) < 0.008) & (np.abs(pos[:, 1] - 0.05) < 0.004) & (pos[:, 2] > 0.08)
    assert lips.sum() > 5 and cheeks.sum() > 5 and brows.sum() > 5
    redness = face[:, 0] - face[:, 1]
    assert redness[lips].mean() > 0.15  # lips red
    assert 0.03 < redness[cheeks].mean() < 0.5 * redness[lips].mean()  # cheeks flushed, less
    assert np.ptp(face[cheeks | lips | brows].mean(axis=1)) > 0.3 and face[brows].mean() < 0.6
    mouth = _attribute(prepared[0], "M_GumsTongue", "COLOR_0")[:, :3]
    gums = by_name(primitives, "M_GumsTongue").positions
    front, back = gums[:, 2] > np.percentile(gums[:, 2], 90), gums[:, 2] < np.percentile(gums[:, 2], 10)
    assert mouth[front].mean() > 5 * mouth[back].mean()  # the throat is darker than the front of the mouth
    occlusion = _attribute(prepared[0], "M_GumsTongue", "_OCCLUSION")
    assert occlusion[front].mean() > 5 * occlusion[back].mean() and occlusion.max() <= 1.0  # the highlights too


def test_the_cavity_is_dark_and_the_scalp_under_the_hair(prepared, ict_head):
    """The ICT head's mouth bag (a part of its back-of-head primitive) is painted dark with depth; the
    scalp is painted dark where the hair covers it, the neck is left as it was."""
    from vispeech.motion.rigging.mouth import cavity

    original = read_primitives(ict_head)
    walls = cavity(original, skin_primitive(original))
    back = by_name(original, "M_BackHead")
    (mask,) = walls.values()
    assert list(walls) == [(back.mesh, back.index)] and 1500 < mask.sum() < 3000
    colours = _attribute(prepared[0], "M_BackHead", "COLOR_0")[:, :3]
    pos = back.positions
    assert colours[mask].mean() < 0.3 and colours[mask & (pos[:, 2] < 0.04)].max() < 0.1
    scalp, neck = ~mask & (pos[:, 1] > 0.12), ~mask & (pos[:, 1] < -0.1)
    assert colours[scalp].max() < 0.1 and np.allclose(colours[neck], 1.0, atol=0.01)


def test_the_tongue_rests_low_and_the_upper_teeth_show(prepared, ict_head):
    """The tongue's top lies 4 mm below the lower incisors' edge over its front 60 %, its underside
    and the gums where they were; the upper front teeth are lowered to 4 mm below the upper lip's
    lowest point, the back and lower teeth where they were."""
    _, report, primitives = prepared
    assert report.reshaped == ["M_GumsTongue", "M_Teeth"]
    original = read_primitives(ict_head)
    tongue = find_tongue(original, ict_head)
    before, after = tongue.primitive.positions, by_name(primitives, "M_GumsTongue").positions
    teeth_before, teeth_after = tongue.teeth.positions, by_name(primitives, "M_Teeth").positions
    lower = teeth_before[~tongue.fixed_teeth]
    edge = lower[lower[:, 2] > lower[:, 2].max() - 0.004, 1].max()
    core = tongue.core
    s = (before[core, 2].max() - before[core, 2]) / np.ptp(before[core, 2])
    front = core[(s <= 0.6) & (np.abs(before[core, 0]) < 0.004)]  # along the midline
    assert after[front, 1].max() == pytest.approx(edge - 0.004, abs=5e-4)
    assert before[front, 1].max() > edge  # it was higher than the teeth
    assert np.array_equal(after[tongue.weights == 0], before[tongue.weights == 0])
    assert np.abs(after[core, 1] - before[core, 1])[before[core, 1] < np.percentile(before[core, 1], 10)].max() < 5e-4
    moved = np.linalg.norm(teeth_after - teeth_before, axis=1) > 0
    assert moved.any() and np.all(tongue.fixed_teeth[moved])
    assert np.all(teeth_before[moved, 2] > teeth_before[:, 2].max() - 0.02)  # only the front ones
    upper = tongue.fixed_teeth & (teeth_before[:, 2] > teeth_before[:, 2].max() - 0.004)
    assert teeth_after[upper, 1].min() == pytest.approx(-0.0332 - 0.004, abs=3e-4)  # the ICT head's upper lip: -33.2 mm


def test_hair_grows_above_the_hairline_and_moves_with_the_forehead(prepared, ict_head):
    """The hair cap lies over the skin above the hairline, ragged at its edge (alpha 0 there,
    with a strand texture), and rises with the brows as the forehead under it does."""
    from scipy.spatial import cKDTree

    from vispeech.motion.rigging.face import find_face
    from vispeech.motion.rigging.head_hair import find_hairline

    out, report, primitives = prepared
    assert report.added == ["vispeech_hair", "vispeech_eyelashes"]
    original = read_primitives(ict_head)
    skin = skin_primitive(original)
    hairline = find_hairline(find_face(skin), skin, [by_name(original, "M_BackHead")])
    hair = by_name(primitives, "vispeech_hair")
    assert 1000 < len(hair.positions) < 5000
    above = hairline.above(hair.positions)
    surface = np.concatenate([skin.positions, by_name(original, "M_BackHead").positions])
    gap = cKDTree(surface).query(hair.positions)[0]
    assert gap.min() > 2e-4 and np.percentile(gap, 90) < 0.015  # on the skin, never in it, a short cut
    alpha = _attribute(out, "vispeech_hair", "COLOR_0")[:, 3]
    assert alpha[above < 0.0005].max() < 0.2 and alpha[above > 0.01].min() == 1.0
    assert above[alpha >= 0.5].min() > 0  # what shows of it is above the hairline
    gltf = pygltflib.GLTF2.load(str(out))
    material = next(m for m in gltf.materials if m.name == "vispeech_hair")
    assert material.alphaMode == "MASK" and material.pbrMetallicRoughness.baseColorTexture is not None
    assert gltf.images[-1].mimeType == "image/png" and gltf.binary_blob()[
        gltf.bufferViews[gltf.images[-1].bufferView].byteOffset :][:8] == b"\x89PNG\r\n\x1a\n"
    forehead = hair.positions[:, 2] > 0.07
    assert hair.targets["browInnerUp"][forehead, 1].max() > 3e-4  # raised with the brows
    assert not np.any(hair.targets["jawOpen"][hair.positions[:, 1] > 0.1])  # the crown stays


def test_eyelashes_grow_from_the_lids_and_close_with_them(prepared):
    """Curled lashes in front of each eye, the upper ones rising forward from the upper lid, the
    lower ones falling from the lower; blinking takes the upper ones down with the lid."""
    _, _, primitives = prepared
    lashes = by_name(primitives, "vispeech_eyelashes")
    pos = lashes.positions
    assert len(pos) == 2 * (28 + 14) * 6
    per_lash = pos.reshape(-1, 6, 3)
    rise = per_lash[:, -1, 1] - per_lash[:, 0, 1]
    reach = per_lash[:, -1, 2] - per_lash[:, 0, 2]
    upper = rise > 0
    assert upper.sum() == 56 and np.all(reach > 0.002)  # all point forward
    assert np.all(rise[upper] > 0.002) and np.all(rise[~upper] < -0.0005)
    for side, blink in ((1, "eyeBlinkLeft"), (-1, "eyeBlinkRight")):
        on_side = np.sign(per_lash[:, 0, 0]) == side
        drop = lashes.targets[blink].reshape(-1, 6, 3)[:, 0, 1]
        assert drop[upper & on_side].mean() < -0.005 and np.all(drop[~on_side] == 0)


def _attribute(path, material, name):
    """A vertex attribute (as floats) of the primitive with ``material``, read with pygltflib alone."""
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob()
    for primitive in gltf.meshes[0].primitives:
        if gltf.materials[primitive.material].name == material:
            accessor = gltf.accessors[getattr(primitive.attributes, name)]
            view = gltf.bufferViews[accessor.bufferView]
            start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
            width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[accessor.type]
            dtype = {5126: "<f4", 5121: "u1"}[accessor.componentType]
            values = np.frombuffer(blob, dtype, count=width * accessor.count, offset=start).reshape(accessor.count, -1)
            return values / 255.0 if accessor.normalized else values.astype(float).squeeze()
    raise AssertionError(material)


def test_the_prepared_file_stays_compressed_and_small(prepared, ict_head):
    out, _, _ = prepared
    gltf = pygltflib.GLTF2.load(str(out))
    assert "EXT_meshopt_compression" in gltf.extensionsUsed
    assert out.stat().st_size < 1.5 * ict_head.stat().st_size  # hair, lashes and a painted mouth included
    assert gltf.meshes[0].extras["targetNames"][-4:] == list(TONGUE_CHANNELS)
    assert len(gltf.meshes[0].weights) == len(gltf.meshes[0].extras["targetNames"]) == 55


def test_the_shipped_head_is_the_ict_head_as_rig_prepare_writes_it_now(prepared):
    """The package's default head is `vispeech rig prepare shared/assets/ict_head.glb` byte for byte,
    so a change to the preparation (tongue targets, paint) shows here until the head is prepared
    again: vispeech rig prepare ../shared/assets/ict_head.glb -o src/vispeech/motion/rigging/data/ict_head.glb"""
    out, _, _ = prepared
    assert DEFAULT_HEAD.read_bytes() == out.read_bytes()
    assert (DEFAULT_HEAD.parent / "LICENSE-ICT-FaceKit.txt").read_text().startswith("MIT License")


def test_cli_prepares_once_and_explains(prepared, ict_head, tmp_path):
    runner = CliRunner()
    result = runner.invoke(main, ["rig", "prepare", str(ict_head), "-o", str(tmp_path / "a.glb")])
    assert result.exit_code == 0, result.output
    assert "tongueTipUp" in result.output and "M_Face" in result.output
    again = runner.invoke(main, ["rig", "prepare", str(tmp_path / "a.glb"), "-o", str(tmp_path / "b.glb")])
    assert again.exit_code == 0 and "none added" in again.output and "already coloured" in again.output
    same = runner.invoke(main, ["rig", "prepare", str(tmp_path / "a.glb"), "-o", str(tmp_path / "a.glb")])
    assert same.exit_code != 0 and same.output.count("\n") == 1 and "another file" in same.output
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a glb")
    result = runner.invoke(main, ["rig", "prepare", str(bad), "-o", str(tmp_path / "c.glb")])
    assert result.exit_code != 0 and result.output.count("\n") == 1 and "not a binary glTF" in result.output
    assert not (tmp_path / "c.glb").exists()


def test_a_head_without_a_tongue_or_features_is_copied_with_notes(tmp_path):
    """A head whose meshes name no tongue and whose skin has no lips or eyes to paint by: copied
    unchanged, with a note for each; find_tongue's error."""
    from test_gltf import tiny_glb

    path = tmp_path / "tiny.glb"
    tiny_glb(path, ["jawOpen", "eyeBlinkLeft"])
    with pytest.raises(VispeechError, match="named for the tongue"):
        find_tongue(read_primitives(path), path)
    report = prepare_head(path, tmp_path / "out.glb")
    assert report.targets == [] and report.painted == []
    assert any("named for the tongue" in note for note in report.notes)
    assert any("mouth hole and two eye holes" in note for note in report.notes)
    assert read_primitives(tmp_path / "out.glb")[0].targets.keys() == {"jawOpen", "eyeBlinkLeft"}


def test_a_gltf_export_onto_the_prepared_head_animates_the_tongue(prepared, tmp_path):
    from vispeech import Track
    from vispeech.motion.formats.gltf import write_gltf_animation

    out, _, _ = prepared
    values = np.zeros((10, 3))
    values[:, 0] = np.linspace(0, 0.3, 10)
    values[4, 1] = 1.0
    track = Track(values, ("jawOpen", "tongueTipUp", "tongueBack"), 25.0)
    write_gltf_animation(track, out, tmp_path / "anim.glb")
    gltf = pygltflib.GLTF2.load(str(tmp_path / "anim.glb"))
    names = gltf.meshes[0].extras["targetNames"]
    sampler = gltf.animations[0].samplers[0]
    accessor = gltf.accessors[sampler.output]
    view = gltf.bufferViews[accessor.bufferView]
    weights = np.frombuffer(gltf.binary_blob(), "<f4", count=accessor.count,
                            offset=(view.byteOffset or 0) + (accessor.byteOffset or 0)).reshape(10, len(names))
    assert weights[4, names.index("tongueTipUp")] == 1.0 and weights[:, names.index("tongueTipUp")].sum() == 1.0
    np.testing.assert_allclose(weights[:, names.index("jawOpen")], values[:, 0], rtol=1e-6)
    assert not weights[:, names.index("tongueBodyUp")].any()
