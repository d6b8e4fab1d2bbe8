"""Taylor rig-space retargeting: principal modes, reference poses, artist rig poses, ``vispeech rig``."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_train_cli import write_takes

from vispeech import Track, VispeechError
from vispeech.cli import main
from vispeech.motion.formats.livelink import read_livelink_csv, write_livelink_csv
from vispeech.motion.formats.registry import read_track, write_track
from vispeech.motion.rigging.rigspace import RigSpace, parse_pose_name, pose_name

CHANNELS = ("jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthSmileLeft")
CONTROLS = ("jaw_rot", "lip_seal", "pout", "smile")


def _tracks(seed=0, n=3):
    """Tracks whose mouth channels vary along a few directions of very different size, plus an eye channel."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(5, 5))
    scale = np.array([0.3, 0.15, 0.08, 0.04, 0.01])
    tracks = []
    for _ in range(n):
        frames = 0.3 + (rng.normal(size=(40, 5)) * scale) @ directions / 5
        values = np.column_stack([frames, rng.random(40)])
        tracks.append(Track(values, (*CHANNELS, "eyeBlinkLeft"), 25.0))
    return tracks


def _rig(space, n_modes=4, seed=1):
    rng = np.random.default_rng(seed)
    poses = {"mean": dict(zip(CONTROLS, rng.random(4)))}
    for k in range(1, n_modes + 1):
        for sigma in (-3, 3):
            poses[pose_name(k, sigma)] = dict(zip(CONTROLS, rng.random(4)))
    return poses


@pytest.fixture
def space():
    return RigSpace().fit(_tracks())


def test_modes_are_the_principal_components(space):
    assert space.channels == CHANNELS  # mouth channels only, in ARKit order
    frames = np.concatenate([t.select(CHANNELS).values for t in _tracks()])
    variances, vectors = np.linalg.eigh(np.cov(frames, rowvar=False))
    np.testing.assert_allclose(space.sd**2, variances[::-1], rtol=1e-9)
    np.testing.assert_allclose(np.abs(space.modes @ vectors[:, ::-1]), np.eye(5), atol=1e-9)
    np.testing.assert_allclose(space.mean, frames.mean(axis=0))
    assert space.explained.sum() == pytest.approx(1.0) and np.all(np.diff(space.sd) < 0)
    largest = np.abs(space.modes).argmax(axis=1)
    assert np.all(space.modes[np.arange(5), largest] > 0)


def test_reference_poses_sit_at_three_sigma(space):
    poses = space.reference_poses()
    assert list(poses) == ["mean", "mode1-3sd", "mode1+3sd", "mode2-3sd", "mode2+3sd",
                           "mode3-3sd", "mode3+3sd", "mode4-3sd", "mode4+3sd"]
    np.testing.assert_allclose(poses["mode2+3sd"], space.mean + 3 * space.sd[1] * space.modes[1])
    track = Track(np.array(list(poses.values())), CHANNELS, 25.0)
    coordinates = space.project(track)
    np.testing.assert_allclose(coordinates[2], [3 * space.sd[0], 0, 0, 0, 0], atol=1e-12)
    assert len(space.reference_poses(2, (-2.0, 1.0, 2.0))) == 7
    with pytest.raises(VispeechError, match="n_modes"):
        space.reference_poses(6)
    assert parse_pose_name("mode12-2.5sd") == (12, -2.5) and pose_name(12, -2.5) == "mode12-2.5sd"
    for sigma in (1e-05, -2.5e-7, 3.0):  # every name export-poses writes reads back (1e-05 prints as 1e-05)
        assert parse_pose_name(pose_name(2, sigma)) == (2, sigma)
    for zero in ("mode1-0sd", "mode1+0.0sd", "mode1+0e3sd"):  # the mean: a rig pose at 0 σ would divide by 0
        with pytest.raises(VispeechError, match="0 standard deviations"):
            parse_pose_name(zero)


def test_reference_poses_map_exactly_onto_the_artist_poses(space):
    rig = _rig(space)
    space.set_rig(rig)
    poses = space.reference_poses()
    out = space.retarget(Track(np.array(list(poses.values())), CHANNELS, 30.0, start_time=1.5))
    assert out.channels == CONTROLS and out.fps == 30.0 and out.start_time == 1.5
    expected = np.array([[rig[name][c] for c in CONTROLS] for name in poses])
    np.testing.assert_allclose(out.values, expected, atol=1e-12)


def test_each_mode_maps_piecewise_linearly_and_modes_add(space):
    rig = _rig(space)
    space.set_rig(rig)
    r = {name: np.array([pose[c] for c in CONTROLS]) for name, pose in rig.items()}
    t = np.array([-4.5, -3.0, -1.0, 0.0, 0.5, 2.0, 3.0, 6.0])  # in standard deviations of mode 2
    frames = space.mean + (t * space.sd[1])[:, None] * space.modes[1]
    out = space.retarget(Track(frames, CHANNELS, 25.0)).values
    for u, row in zip(t, out):
        side = r["mode2+3sd"] if u > 0 else r["mode2-3sd"]
        np.testing.assert_allclose(row, r["mean"] + abs(u) / 3 * (side - r["mean"]), atol=1e-12)
    both = space.mean + 1.5 * space.sd[0] * space.modes[0] - 0.6 * space.sd[2] * space.modes[2]
    combined = space.retarget(Track(both[None], CHANNELS, 25.0)).values[0]
    expected = r["mean"] + 0.5 * (r["mode1+3sd"] - r["mean"]) + 0.2 * (r["mode3-3sd"] - r["mean"])
    np.testing.assert_allclose(combined, expected, atol=1e-12)
    # mode 5 has no rig poses: motion along it is ignored
    np.testing.assert_allclose(space.retarget(Track((space.mean + space.modes[4])[None], CHANNELS, 25.0)).values[0],
                               r["mean"], atol=1e-12)


def test_the_pose_sheet_as_rig_reconstructs_from_the_modes(space, tmp_path):
    space.write_pose_sheet(tmp_path / "sheet.json")
    sheet = json.loads((tmp_path / "sheet.json").read_text())
    assert sheet["channels"] == list(CHANNELS) and [m["mode"] for m in sheet["modes"]] == [1, 2, 3, 4]
    space.load_rig(tmp_path / "sheet.json")  # the ARKit face itself as the target rig
    track = _tracks(seed=5, n=1)[0]
    coordinates = space.project(track)[:, :4]
    np.testing.assert_allclose(space.retarget(track).values, space.mean + coordinates @ space.modes[:4], atol=1e-12)

    space.write_pose_sheet(tmp_path / "sheet.csv", n_modes=2)
    rows = list(csv.reader((tmp_path / "sheet.csv").open()))
    assert rows[0] == ["pose", *CHANNELS] and [row[0] for row in rows[1:]] == [
        "mean", "mode1-3sd", "mode1+3sd", "mode2-3sd", "mode2+3sd"]
    assert float(rows[3][1]) == pytest.approx(space.reference_poses(2)["mode1+3sd"][0], abs=1e-6)


def test_save_and_load_round_trip_exactly(space, tmp_path):
    space.set_rig(_rig(space, n_modes=2), clip=(0.0, 0.9))
    space.save(tmp_path / "space")
    loaded = RigSpace.load(tmp_path / "space")
    for name in ("mean", "modes", "sd", "explained", "rig_mean"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(space, name))
    assert loaded.channels == space.channels and loaded.rig_controls == CONTROLS and loaded.clip == (0.0, 0.9)
    track = _tracks(seed=3, n=1)[0]
    np.testing.assert_array_equal(loaded.retarget(track).values, space.retarget(track).values)
    assert loaded.retarget(track).values.max() <= 0.9
    (tmp_path / "space" / "modes.npz").write_bytes(b"garbage")
    with pytest.raises(VispeechError, match="cannot read"):
        RigSpace.load(tmp_path / "space")
    with pytest.raises(VispeechError, match="no rig space"):
        RigSpace.load(tmp_path / "nowhere")


@pytest.mark.parametrize(("change", "message"), [
    (lambda r: r.pop("mean"), "need a 'mean' pose"),
    (lambda r: r.pop("mode3+3sd"), "mode 3 needs one rig pose below the mean and one above"),
    (lambda r: r.update({"mode3-2sd": {}}), "mode 3 needs one rig pose below"),
    (lambda r: r.update({"mode9-3sd": {}, "mode9+3sd": {}}), "only 5 modes"),
    (lambda r: r.update({"mode1+3.0sd": {}}), "given twice"),
    (lambda r: r.update({"wide": {}}), "neither 'mean' nor like"),
    (lambda r: r["mode1-3sd"].update({"brow": 1.0}), "sets 'brow', which the mean pose does not name"),
    (lambda r: r["mode1-3sd"].update({"pout": "x"}), "'pout' is not a number"),
])
def test_bad_rig_poses_are_refused(space, change, message):
    rig = _rig(space)
    change(rig)
    with pytest.raises(VispeechError, match=message):
        space.set_rig(rig)


def test_a_pose_may_leave_out_controls_at_the_mean(space):
    rig = _rig(space, n_modes=1)
    del rig["mode1+3sd"]["pout"]
    space.set_rig(rig)
    assert space.rig_poses[1][3.0][CONTROLS.index("pout")] == rig["mean"]["pout"]


def test_unfitted_or_rigless_space_refuses(space):
    with pytest.raises(VispeechError, match="not fitted"):
        RigSpace().reference_poses()
    with pytest.raises(VispeechError, match="no rig poses"):
        space.retarget(_tracks()[0])
    with pytest.raises(VispeechError, match="lacks channels mouthPucker"):
        RigSpace(["jawOpen", "mouthPucker"]).fit([Track(np.zeros((4, 1)), ("jawOpen",), 25.0)])


def test_rig_cli_exports_imports_and_retargets(tmp_path):
    takes = write_takes(tmp_path / "takes", ids=["a", "b", "c"])
    rng = np.random.default_rng(0)
    for name in "abc":  # mouth motion in more directions than the jaw's
        track = read_livelink_csv(takes / f"{name}.csv")
        for channel in CHANNELS[1:]:
            track.values[:, track.index(channel)] = rng.random(track.n_frames) * 0.2
        write_livelink_csv(track, takes / f"{name}.csv")
    runner = CliRunner()
    result = runner.invoke(main, ["rig", "export-poses", "--corpus", str(takes), "--language", "en", "-o",
                                  str(tmp_path / "p.json"), "--modes", "2", "--save-space", str(tmp_path / "space")])
    assert result.exit_code == 0, result.output
    assert "modes 1-2 explain" in result.output and "5 poses ->" in result.output
    sheet = json.loads((tmp_path / "p.json").read_text())
    names = list(sheet["poses"])
    assert names == ["mean", "mode1-3sd", "mode1+3sd", "mode2-3sd", "mode2+3sd"]

    artist = {"poses": {name: {"jaw_rot": 10.0 * i, "smile": 1.0} for i, name in enumerate(names)}}
    (tmp_path / "rig.json").write_text(json.dumps(artist))
    result = runner.invoke(main, ["rig", "import", str(tmp_path / "rig.json"), "--space", str(tmp_path / "space"),
                                  "-o", str(tmp_path / "rigged")])
    assert result.exit_code == 0, result.output
    assert "2 rig controls on modes 1, 2" in result.output

    poses = RigSpace.load(tmp_path / "space").reference_poses(2)
    channels = tuple(sheet["channels"])
    write_track(Track(np.array(list(poses.values())), channels, 30.0), tmp_path / "in.json")
    result = runner.invoke(main, ["rig", "retarget", str(tmp_path / "in.json"), "-s", str(tmp_path / "rigged"),
                                  "-o", str(tmp_path / "out.json")])
    assert result.exit_code == 0, result.output
    out = read_track(tmp_path / "out.json")
    assert out.channels == ("jaw_rot", "smile")
    np.testing.assert_allclose(out["jaw_rot"], [0, 10, 20, 30, 40], atol=1e-4)

    refit = runner.invoke(main, ["rig", "import", str(tmp_path / "rig.json"), "--corpus", str(takes),
                                 "--language", "en", "-o", str(tmp_path / "refit")])
    assert refit.exit_code == 0, refit.output
    np.testing.assert_array_equal(RigSpace.load(tmp_path / "refit").modes, RigSpace.load(tmp_path / "rigged").modes)
    default = runner.invoke(main, ["rig", "export-poses", "--corpus", str(takes), "-o", str(tmp_path / "q.json")])
    assert default.exit_code == 0, default.output  # --language defaults to en, as in every command
    swedish = runner.invoke(main, ["rig", "export-poses", "--corpus", str(takes), "-l", "sv", "-o",
                                   str(tmp_path / "q.json")])
    assert swedish.exit_code == 2 and "no usable utterances (skipped take a:" in swedish.output
    bad = runner.invoke(main, ["rig", "import", str(tmp_path / "rig.json"), "-o", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "exactly one of --space and --corpus" in bad.output
    (tmp_path / "rig.json").write_text(json.dumps({"poses": {"mean": {"a": 1}, "mode1-3sd": {"a": 0}}}))
    bad = runner.invoke(main, ["rig", "retarget", str(tmp_path / "in.json"), "-s", str(tmp_path / "space"),
                               "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o.json")])
    assert bad.exit_code == 2 and "rig.json: mode 1 needs one rig pose" in bad.output
    assert not (tmp_path / "o.json").exists()
    for args in (["mouth-frames", "--corpus", str(takes), "--seed", "-1", "-o", str(tmp_path / "m.npz")],
                 ["export-poses", "--corpus", str(takes), "--sigma", "1e308", "-o", str(tmp_path / "far.json")]):
        bad = runner.invoke(main, ["rig", *args])  # refused by the option, before any work
        assert bad.exit_code == 2 and "Invalid value" in bad.output, bad.output
        assert not Path(args[-1]).exists()
    (tmp_path / "taken").write_text("a file where a folder goes")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    for args, message in (
        (["export-poses", "--corpus", str(takes), "-o", str(tmp_path / "p2.json"), "--save-space",
          str(tmp_path / "mine")], "holds files vispeech did not write"),  # nothing written, not even p2.json
        (["export-poses", "--corpus", str(takes), "-o", str(tmp_path / "taken" / "p2.json")], "cannot write"),
        (["mouth-frames", "--corpus", str(takes), "-o", str(tmp_path / "taken" / "m.npz")], "cannot write"),
        (["import", str(tmp_path / "rig.json"), "--corpus", str(takes), "-o", str(tmp_path / "mine")], "notes.txt"),
        (["retarget", str(tmp_path / "in.json"), "-s", str(tmp_path / "space"), "-o", str(tmp_path / "o.glb")],
         "write the rig's controls as .json"),
    ):
        bad = runner.invoke(main, ["rig", *args])
        assert bad.exit_code == 2 and message in bad.output, bad.output
    assert not (tmp_path / "p2.json").exists() and not (tmp_path / "o.glb").exists()
