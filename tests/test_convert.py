"""``vispeech convert``: between track formats, resampling, retargeting, clean errors."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from vispeech import Phone, PhoneSequence, Track
from vispeech.cli import main
from vispeech.motion.formats.animation_json import read_animation_json, write_animation_json
from vispeech.motion.formats.livelink import LIVELINK_CHANNELS, write_livelink_csv
from vispeech.motion.formats.registry import read_track


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_clean_error(result, text):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.strip().splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("error:") and text in lines[0], result.output


@pytest.fixture
def take(tmp_path):
    """A 2-second Live Link take at 60 fps with the jaw opening and closing."""
    t = np.arange(120) / 60
    values = np.zeros((120, len(LIVELINK_CHANNELS)))
    values[:, LIVELINK_CHANNELS.index("jawOpen")] = np.round(0.5 - 0.5 * np.cos(2 * np.pi * t), 10)
    path = tmp_path / "take.csv"
    write_livelink_csv(Track(values, LIVELINK_CHANNELS, 60.0), path)
    return path


def test_livelink_to_json_and_back_is_exact(tmp_path, take):
    assert run("convert", take, tmp_path / "a.json").exit_code == 0
    result = run("convert", tmp_path / "a.json", tmp_path / "b.csv")
    assert result.exit_code == 0, result.output
    assert "120 frames at 60 fps" in result.output
    track = read_track(tmp_path / "b.csv")
    assert np.allclose(track["jawOpen"], read_track(take)["jawOpen"], atol=5e-7)


def test_resample_to_talkinghead(tmp_path, take):
    result = run("convert", take, tmp_path / "t.json", "--to", "talkinghead", "--fps", 30)
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "t.json").read_text())
    assert len(data["dt"]) == 60 and data["dt"][0] == pytest.approx(1000 / 30)
    assert np.allclose(data["vs"]["jawOpen"], read_track(take)["jawOpen"][::2], atol=1e-6)


def test_retarget_with_pose_table_and_mouth_cues(tmp_path, take):
    result = run("convert", take, tmp_path / "rig.json", "--pose-table", "thesis_bone_rig")
    assert result.exit_code == 0, result.output
    rig = read_track(tmp_path / "rig.json")
    assert np.allclose(rig["jaw.rotation_x"], 0.35 * read_track(take)["jawOpen"], atol=1e-6)
    assert run("convert", take, tmp_path / "cues.tsv").exit_code == 0
    lines = (tmp_path / "cues.tsv").read_text().splitlines()
    assert lines[0] == "0.00\tX" and lines[-1] == "2.00\tX" and len(lines) >= 3
    assert run("convert", take, tmp_path / "v.csv", "--to", "OCULUS").exit_code == 0
    assert (tmp_path / "v.csv").read_text().startswith("time,sil,PP,FF,TH,DD,kk,CH,SS,nn,RR,aa,E,ih,oh,ou\n")


def test_json_keeps_phones_and_audio(tmp_path, take):
    phones = PhoneSequence([Phone("sil", 0.0, 1.0), Phone("AA", 1.0, 2.0, None, 1)], "en")
    write_animation_json(read_track(take), tmp_path / "in.json", phones=phones, audio="take.wav")
    assert run("convert", tmp_path / "in.json", tmp_path / "out.json", "--fps", 30).exit_code == 0
    out = read_animation_json(tmp_path / "out.json")
    assert out.phones == phones and out.audio == "take.wav" and out.track.fps == 30.0
    assert run("convert", tmp_path / "in.json", tmp_path / "cues.rhubarb.json").exit_code == 0
    assert json.loads((tmp_path / "cues.rhubarb.json").read_text())["metadata"]["soundFile"] == "take.wav"


def _glb_weights(path):
    """Morph target names and the (frames x targets) weights of the animation in the GLB at ``path``."""
    import pygltflib

    gltf = pygltflib.GLTF2.load(str(path))
    names = gltf.meshes[0].extras["targetNames"]
    accessor = gltf.accessors[gltf.animations[0].samplers[0].output]
    view = gltf.bufferViews[accessor.bufferView]
    weights = np.frombuffer(gltf.binary_blob(), "<f4", count=accessor.count,
                            offset=(view.byteOffset or 0) + (accessor.byteOffset or 0))
    return names, weights.reshape(-1, len(names))


def test_glb_output_onto_the_shipped_head_or_another(tmp_path, take, shared_dir):
    """Without --glb the animation goes onto the shipped head, tongue morph targets and all, kept
    meshopt-compressed (--uncompressed decodes it); the channels a head cannot show are named in
    one warning line."""
    from vispeech.motion.rigging.head import DEFAULT_HEAD

    head_pose = "headYaw, headPitch, headRoll, leftEyeYaw, leftEyePitch, leftEyeRoll, rightEyeYaw, rightEyePitch, " \
                "rightEyeRoll"
    result = run("convert", take, tmp_path / "head.glb")
    assert result.exit_code == 0, result.output
    assert result.stderr.splitlines() == [f"warning: ict_head.glb has no morph target for 9 of the track's channels, "
                                          f"which are left out: {head_pose}"]
    names, weights = _glb_weights(tmp_path / "head.glb")
    assert "tongueTipUp" in names and weights.shape == (120, len(names))
    np.testing.assert_allclose(weights[:, names.index("jawOpen")], read_track(take)["jawOpen"], atol=1e-6)
    size = (tmp_path / "head.glb").stat().st_size
    assert size < DEFAULT_HEAD.stat().st_size + 4 * 120 * (1 + len(names)) + 4096
    other = run("convert", take, tmp_path / "raw.glb", "--glb", shared_dir / "assets/ict_head.glb", "--uncompressed")
    assert other.exit_code == 0, other.output
    assert other.stderr.splitlines() == [f"warning: ict_head.glb has no morph target for 10 of the track's channels, "
                                         f"which are left out: tongueOut, {head_pose}"]
    names, weights = _glb_weights(tmp_path / "raw.glb")
    assert "tongueTipUp" not in names
    np.testing.assert_allclose(weights[:, names.index("jawOpen")], read_track(take)["jawOpen"], atol=1e-6)
    assert (tmp_path / "raw.glb").stat().st_size > 5 * size  # decoded


@pytest.mark.parametrize("args,text", [
    (["missing.csv", "out.json"], "not found"),
    (["take.csv", "out.xyz"], "cannot tell the track format"),
    (["take.csv", "out.json", "--to", "usd"], "unknown track format 'usd'"),
    (["take.csv", "out.glb", "--glb", "none.glb"], "base model not found"),
    (["take.csv", "out.json", "--fps", "0"], "--fps must be positive"),
    (["take.csv", "out.json", "--pose-table", "nope"], "pose table not found"),
    (["take.csv", "out.tsv", "--to", "rhubarb", "--pose-table", "thesis_bone_rig"], "need a morph pose table"),
    (["take.csv", "out.visemes.csv", "--pose-table", "rhubarb_shapes"], "no control for viseme(s) sil, PP"),
    (["take.csv", "out.json", "--to", "livelink"], "a livelink file is .csv, not .json"),  # would not read back
    (["take.csv", "out.csv", "--to", "gltf"], "a gltf file is .glb, not .csv"),
])
def test_errors_are_one_line_and_write_nothing(tmp_path, take, monkeypatch, args, text):
    monkeypatch.chdir(tmp_path)
    before = {p.name for p in tmp_path.iterdir()}
    assert_clean_error(run("convert", *args), text)
    assert {p.name for p in tmp_path.iterdir()} == before


def test_to_names_a_format_of_the_same_kind_of_file(tmp_path, take):
    """--to picks among the formats a file's extension allows: Oculus visemes are a CSV too."""
    assert run("convert", take, tmp_path / "v.csv", "--to", "oculus").exit_code == 0
    assert (tmp_path / "v.csv").read_text().startswith("time,sil,PP,FF,")


def test_rhubarb_input_cannot_be_read(tmp_path, take):
    assert run("convert", take, tmp_path / "c.rhubarb.json").exit_code == 0
    assert_clean_error(run("convert", tmp_path / "c.rhubarb.json", tmp_path / "x.json"), "cannot be read")
