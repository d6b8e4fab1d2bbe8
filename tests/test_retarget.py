"""Pose tables: explicit, by-pose and bone tables, the shipped tables, and bad tables."""

import json
from pathlib import Path

import numpy as np
import pytest

import vispeech.motion.rigging
from vispeech import Track, VispeechError
from vispeech.motion.rigging.retarget import BUILTIN_TABLES, PoseTable

DATA = Path(vispeech.motion.rigging.__file__).parent / "data"


def track(**curves) -> Track:
    return Track(np.array(list(curves.values())).T, tuple(curves), 30.0, 1.5)


def test_explicit_morph_table_with_bias_and_range():
    table = PoseTable.from_dict({
        "type": "morph", "range": [0, 1],
        "controls": {"viseme_PP": {"mouthClose": 0.8, "mouthPressLeft": 0.4}, "viseme_aa": {"jawOpen": 1.5}},
        "bias": {"viseme_aa": -0.1},
    })
    out = table.apply(track(jawOpen=[0.0, 0.4, 1.0], mouthClose=[1.0, 0.5, 0.0]))
    assert out.channels == ("viseme_PP", "viseme_aa") and out.fps == 30.0 and out.start_time == 1.5
    assert np.allclose(out["viseme_PP"], [0.8, 0.4, 0.0])  # mouthPressLeft missing -> 0
    assert np.allclose(out["viseme_aa"], [0.0, 0.5, 1.0])  # -0.1 clipped to 0, 1.4 clipped to 1


def test_bone_table_names_channels_bone_dot_channel():
    bones = {"jaw": {"rotation_x": {"jawOpen": 0.35}}, "lip_corner_L": {"translation_x": {"mouthSmileLeft": 0.006}}}
    table = PoseTable.from_dict({"type": "bones", "bones": bones, "bias": {"jaw": {"rotation_x": 0.01}}})
    out = table.apply(track(jawOpen=[0.0, 1.0], mouthSmileLeft=[0.5, 0.0]))
    assert out.channels == ("jaw.rotation_x", "lip_corner_L.translation_x")
    assert np.allclose(out.values, [[0.01, 0.003], [0.36, 0.0]])


def test_pose_decomposition_recovers_mixtures():
    table = PoseTable.from_poses({"a": {"jawOpen": 0.6}, "u": {"mouthFunnel": 1.0}}, rest="sil", ridge=0.0)
    out = table.apply(track(jawOpen=[0.0, 0.6, 0.3], mouthFunnel=[0.0, 0.0, 0.5]))
    assert out.channels == ("a", "u", "sil")
    assert np.allclose(out.values, [[0, 0, 1], [1, 0, 0], [0.5, 0.5, 0]])


@pytest.mark.parametrize("name,rest", [("oculus_visemes", "viseme_sil"), ("rhubarb_shapes", "X")])
def test_shipped_tables_map_each_pose_to_its_control(name, rest):
    table = PoseTable.load(name)
    poses = json.loads((DATA / f"{name}.json").read_text())["poses"]
    assert table.controls == tuple(poses) + (rest,)
    for control, pose in poses.items():
        for strength in (0.7, 1.0, 1.3):
            frame = Track(np.array([[v * strength for v in pose.values()]]), tuple(pose), 30.0)
            out = table.apply(frame).values[0]
            assert table.controls[int(out.argmax())] == control, (control, strength)
    rest_frame = table.apply(Track(np.zeros((1, 1)), ("jawOpen",), 30.0))
    assert rest_frame[rest][0] == 1.0 and rest_frame.values.sum() == 1.0


def test_shipped_bone_rig_has_ten_bones():
    table = PoseTable.load("thesis_bone_rig")
    bones = {c.split(".")[0] for c in table.controls}
    assert table.kind == "bones" and len(bones) == 10
    assert {"jaw", "tongue_back", "tongue_front"} <= bones and sum(b.startswith("lip") for b in bones) == 7
    out = table.apply(track(jawOpen=[0.0, 1.0]))
    assert np.allclose(out["jaw.rotation_x"], [0.0, 0.35])


def test_load_by_path_and_every_builtin(tmp_path):
    for name in BUILTIN_TABLES:
        assert PoseTable.load(name).controls
    path = tmp_path / "mine.json"
    path.write_text(json.dumps({"type": "morph", "controls": {"open": {"jawOpen": 1.0}}}))
    assert PoseTable.load(path).name == "mine"


@pytest.mark.parametrize("data,message", [
    ({"type": "skin"}, "type must be 'morph' or 'bones'"),
    ({"type": "morph"}, "exactly one of 'controls' and 'poses'"),
    ({"type": "morph", "controls": {"a": {"jawOpen": "big"}}}, "'a.jawOpen' must be a number"),
    ({"type": "morph", "controls": {"a": {"jawOpen": 1}}, "bias": {"b": 1}}, "bias for unknown control 'b'"),
    ({"type": "morph", "controls": {"a": {"jawOpen": 1}}, "range": [1, 0]}, "'range' low 1.0 must be below"),
    ({"type": "bones", "bones": {"jaw.bone": {"rotation_x": {"jawOpen": 1}}}}, "must not contain '.'"),
    ({"type": "morph", "poses": {"a": {"jawOpen": 1}, "b": {"jawOpen": 2}}, "ridge": 0}, "linearly dependent"),
    ({"type": "morph", "poses": {"a": {"jawOpen": 1}}, "rest": "a"}, "must not also be a pose"),
])
def test_bad_tables(tmp_path, data, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(VispeechError, match=message):
        PoseTable.load(path)


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(VispeechError, match="built-in tables: oculus_visemes"):
        PoseTable.load(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(VispeechError, match="not valid JSON"):
        PoseTable.load(tmp_path / "bad.json")


def test_track_without_any_input_channel():
    with pytest.raises(VispeechError, match="none of the channels"):
        PoseTable.load("oculus_visemes").apply(track(headYaw=[0.1]))
