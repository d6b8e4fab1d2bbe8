"""Amplitude calibration by geometry (issue 10, part 1): a head's lip gap and width from its morph
targets, gains fitted to the GRID speaker's real lip gap, output scales applied by the commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import SHARED, require
from vispeech.cli import main
from vispeech.errors import VispeechError
from vispeech.evaluation.closures import TRACKED_CLOSED
from vispeech.motion.rigging.calibration import (
    CLOSED_GAP, Calibration, HeadGeometry, compare_gaps, fit_calibration, load_mouth_frames, load_scale,
)
from vispeech.motion.track import Track

ICT_HEAD = SHARED / "assets" / "ict_head.glb"
GRID = SHARED / "data" / "grid_s1"


@pytest.fixture(scope="module")
def head() -> HeadGeometry:
    require(ICT_HEAD.is_file(), f"the ICT head ({ICT_HEAD}, in the shared data folder)")
    return HeadGeometry.from_glb(ICT_HEAD)


@pytest.fixture(scope="module")
def test_frames():
    """The grid_s1 test split's tracked frames with the speaker's lip gap and width."""
    require(GRID.is_dir(), f"grid_s1 ({GRID}, in the shared data folder)")
    from vispeech.corpus.articulation import mouth_frames
    from vispeech.corpus.grid import read_grid

    return mouth_frames(read_grid(GRID).split("test"))


def test_head_geometry_of_the_ict_head(head):
    assert 0.09 < head.eye_distance < 0.12  # metres between the outer eye corners
    assert 0.0 <= head.gap0 < 0.02  # lips together at rest
    assert head.gap_per["jawOpen"] > 0.2 and head.gap_per["mouthClose"] < -0.2  # ARKit's pair
    assert head.gap_per["jawOpen"] + head.gap_per["mouthClose"] < 0.05  # jawOpen = mouthClose keeps lips shut
    assert head.width_per["mouthSmileLeft"] > 0 and head.width_per["mouthPucker"] < 0
    shut = Track(np.array([[0.0, 0.0], [0.4, 0.4], [0.4, 0.0]]), ("jawOpen", "mouthClose"), 30.0)
    gaps = head.gap(shut)
    assert gaps[0] < 0.02 and gaps[1] < 0.03 and gaps[2] > 0.1


def test_the_shipped_arkit_scale_makes_the_head_follow_the_human(head, test_frames):
    """On grid_s1's test split (frames the fit never saw) the ICT head's inner-lip gap over its eye
    distance has the speaker's median and 90th percentile within 10 %; unscaled it is a slit."""
    scores, gap, width = test_frames
    figures = compare_gaps(head, load_scale("arkit").apply(scores), gap, raw=scores)
    assert figures["open_frames"] > 2000
    assert 0.9 <= figures["calibrated"]["median_ratio"] <= 1.1, figures
    assert 0.9 <= figures["calibrated"]["p90_ratio"] <= 1.1, figures
    assert figures["raw"]["median_ratio"] < 0.8 and figures["raw"]["p90_ratio"] < 0.8, figures
    assert figures["calibrated"]["closed_median_gap"] <= TRACKED_CLOSED  # closures stay closed


def test_fit_from_the_shipped_frames_agrees_with_the_shipped_calibration(head):
    scores, gap, width, source = load_mouth_frames()
    assert scores.n_frames == 5000 and "grid_s1" in source and "CC BY 4.0" in source
    fitted = fit_calibration(head, scores, gap, width, "ict")
    shipped = load_scale("arkit")
    assert fitted.gains["jawOpen"] == fitted.gains["mouthClose"]
    assert fitted.gains["jawOpen"] == pytest.approx(shipped.gains["jawOpen"], rel=0.05)
    assert 0.9 <= fitted.fit["calibrated"]["median_ratio"] <= 1.1


def test_fit_needs_open_and_closed_frames(head):
    scores = Track(np.full((20, 2), 0.3), ("jawOpen", "mouthClose"), 25.0)
    with pytest.raises(VispeechError, match="lips apart and frames with them closed"):
        fit_calibration(head, scores, np.full(20, 0.1), np.full(20, 0.5))
    with pytest.raises(VispeechError, match="at least 10 frames"):
        fit_calibration(head, scores, np.full(19, 0.1), np.full(20, 0.5))
    assert CLOSED_GAP == TRACKED_CLOSED


def test_calibration_applies_saves_and_loads(tmp_path):
    calibration = Calibration({"jawOpen": 2.0, "mouthClose": 2.0}, "test head")
    track = Track(np.array([[0.3, 0.1, 0.5], [0.7, 0.6, 0.2]]), ("jawOpen", "mouthClose", "mouthSmileLeft"), 30.0)
    scaled = calibration.apply(track)
    np.testing.assert_allclose(scaled.values, [[0.6, 0.2, 0.5], [1.0, 1.0, 0.2]])  # clipped; others kept
    calibration.save(tmp_path / "head.json")
    assert Calibration.load(tmp_path / "head.json") == calibration
    assert load_scale(tmp_path / "head.json").gains == calibration.gains
    assert load_scale("tracker") is None and load_scale(None) is None
    assert load_scale("arkit").gains["jawOpen"] > 1.3


@pytest.mark.parametrize(("content", "message"), [
    ("not json", "is not JSON"),
    ('{"format": "something-else"}', "is not a vispeech-calibration file"),
    ('{"format": "vispeech-calibration", "gains": {"jawOpen": -1}}', "numbers in \\[0, 4\\]"),
    ('{"format": "vispeech-calibration", "gains": {"jawOpen": true}}', "numbers in"),
])
def test_bad_calibration_files_are_one_line_errors(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(VispeechError, match=message):
        load_scale(path)
    with pytest.raises(VispeechError, match="unknown output scale 'wide'"):
        load_scale("wide")


def test_cli_calibrates_a_head_and_every_command_writes_in_its_scale(head, tmp_path):
    runner = CliRunner()
    done = runner.invoke(main, ["rig", "calibrate", str(ICT_HEAD), "-o", str(tmp_path / "ict.json")])
    assert done.exit_code == 0, done.output
    assert "inner-lip gap, head / human over open frames: median 0.6" in done.output
    saved = json.loads((tmp_path / "ict.json").read_text(encoding="utf-8"))
    assert saved["format"] == "vispeech-calibration" and saved["gains"]["jawOpen"] > 1.3
    assert 0.9 <= saved["fit"]["calibrated"]["median_ratio"] <= 1.1 and saved["fit"]["raw"]["median_ratio"] < 0.8

    from vispeech.motion.formats.registry import read_track

    text = "My mom made a large map."
    jaw = {}
    for scale in ("tracker", "arkit", str(tmp_path / "ict.json")):
        out = tmp_path / f"say-{len(jaw)}"
        said = runner.invoke(main, ["say", text, "-o", str(out), "--scale", scale])
        assert said.exit_code == 0, said.output
        jaw[scale] = read_track(out / "animation.csv")["jawOpen"]
    ratio = jaw["arkit"].max() / jaw["tracker"].max()
    assert ratio == pytest.approx(load_scale("arkit").gains["jawOpen"], rel=0.01)
    assert jaw[str(tmp_path / "ict.json")].max() > 1.3 * jaw["tracker"].max()
    converted = runner.invoke(main, ["convert", str(tmp_path / "say-0" / "animation.csv"),
                                     str(tmp_path / "arkit.csv"), "--scale", "arkit"])
    assert converted.exit_code == 0, converted.output
    np.testing.assert_allclose(read_track(tmp_path / "arkit.csv")["jawOpen"], jaw["arkit"], atol=1e-5)
    refused = runner.invoke(main, ["say", text, "-o", str(tmp_path / "no"), "--scale", "wide"])
    assert refused.exit_code == 2 and "unknown output scale" in refused.output
    assert not (tmp_path / "no").exists()
