"""Avatars users bring: VRM 0.x and 1.0 models (made from the shipped ICT head, tests/vrm_heads.py) in
``rig calibrate`` and ``rig prepare``, and ``vispeech serve --avatar`` with a file or a URL. The
player showing them is tested in Chromium (tests/test_browser.py)."""

from __future__ import annotations

import json
import re
import struct

import numpy as np
import pytest

from click.testing import CliRunner
from conftest import SHARED, require
from vrm_heads import vrm_head

from vispeech.cli import main
from vispeech.errors import VispeechError
from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.motion.rigging.calibration import HeadGeometry
from vispeech.motion.rigging.glb import read_primitives
from vispeech.motion.rigging.head import DEFAULT_HEAD, prepare_head

ICT_HEAD = SHARED / "assets" / "ict_head.glb"


def _json(path):
    data = path.read_bytes()
    return json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])


@pytest.mark.parametrize("version", ["1.0", "0.x"])
def test_calibration_measures_a_perfect_sync_vrm_as_the_head_it_was_made_from(version, tmp_path):
    """A VRM 0.x model faces -Z: it is measured turned to face +Z, as the player shows it."""
    head = HeadGeometry.from_glb(DEFAULT_HEAD)
    vrm = HeadGeometry.from_glb(vrm_head(tmp_path / "head.vrm", version, perfect_sync=True))
    assert (vrm.eye_distance, vrm.gap0, vrm.width0) == pytest.approx((head.eye_distance, head.gap0, head.width0))
    assert vrm.gap_per == pytest.approx(head.gap_per) and vrm.landmarks == head.landmarks


def test_prepare_gives_a_perfect_sync_vrm_a_tongue_and_keeps_it_a_vrm(tmp_path):
    require(ICT_HEAD.is_file(), f"the ICT head ({ICT_HEAD}, in the shared data folder)")
    plain = prepare_head(ICT_HEAD, tmp_path / "plain.glb")
    source = vrm_head(tmp_path / "head.vrm", "0.x", perfect_sync=True, head=ICT_HEAD)
    report = prepare_head(source, tmp_path / "ready.vrm")
    assert report.targets == list(TONGUE_CHANNELS) == plain.targets and report.reshaped == plain.reshaped
    for got, want in zip(read_primitives(tmp_path / "ready.vrm"), read_primitives(tmp_path / "plain.glb")):
        assert got.name == want.name and np.allclose(got.positions, want.positions, atol=1e-6)  # written back turned
    before, after = _json(source)["extensions"]["VRM"], _json(tmp_path / "ready.vrm")["extensions"]["VRM"]
    assert after == before


@pytest.mark.parametrize("command", [["calibrate"], ["prepare"]])
def test_a_vrm_without_arkit_shapes_is_refused_in_one_line(command, tmp_path):
    head = vrm_head(tmp_path / "head.vrm", "1.0")
    result = CliRunner().invoke(main, ["rig", *command, str(head), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert "a VRM without ARKit morph targets" in result.output and "expressions (aa, ih, ou, ee, oh" in result.output
    assert not (tmp_path / "out").exists()


def test_serve_an_avatar_at_a_url_the_browser_loads_and_the_server_never_fetches(tmp_path):
    """--avatar URL: /api/config hands the page the URL (the host must allow it: CORS); the server has
    no file to serve and fetches nothing (this host does not exist). The URL survives the trip to the
    server's other processes; a string that is not an http(s) URL is a file name."""
    from fastapi.testclient import TestClient

    from vispeech.serve import ServeConfig, create_app

    url = "https://avatars.invalid/people/ada.vrm?v=2"
    config = ServeConfig(avatar=url, avatar_credit="Ada, CC0", cache=":memory:")
    assert ServeConfig.from_json(config.to_json()).avatar == url
    with TestClient(create_app(config)) as client:
        got = client.get("/api/config").json()
        assert (got["avatar_url"], got["avatar_credit"]) == (url, "Ada, CC0")
        assert client.get("/avatar.glb").status_code == 404
    local = ServeConfig(avatar=str(tmp_path / "ada.vrm"))
    assert local.avatar == tmp_path / "ada.vrm" and ServeConfig.from_json(local.to_json()).avatar == local.avatar
    result = CliRunner().invoke(main, ["serve", "--avatar", "ftp://avatars.invalid/ada.vrm", "--cache", ":memory:"])
    assert result.exit_code == 2 and "not a ftp:// URL" in result.output  # a scheme no page loads


def test_serve_a_vrm_file_as_it_is_when_it_has_no_arkit_shapes_to_prepare(tmp_path, caplog):
    from fastapi.testclient import TestClient

    from vispeech.serve import ServeConfig, create_app

    head = vrm_head(tmp_path / "head.vrm", "0.x")
    with TestClient(create_app(ServeConfig(avatar=head, cache=":memory:"))) as client:
        assert client.get("/api/config").json()["avatar_url"] == "/avatar.glb"
        assert client.get("/avatar.glb").content == head.read_bytes()
    assert "a VRM without ARKit morph targets" in caplog.text
    for name, content in (("bad.glb", b"not a glb\n"), ("empty.glb", b""), ("text.vrm", b"{}")):
        (tmp_path / name).write_bytes(content)  # no head a browser could load: refused at start, not served
        with pytest.raises(VispeechError, match=re.escape(f"avatar {tmp_path / name} is not a binary glTF (.glb) or VRM")):
            create_app(ServeConfig(avatar=tmp_path / name, cache=":memory:"))


def test_rig_says_in_one_line_what_it_cannot_do_with_an_avatar_without_arkit_shapes(tmp_path):
    """A VRM whose morph targets have no ARKit names (tests/vrm_heads.py: the ICT head, renamed)."""
    from vrm_heads import vrm_head

    vrm = vrm_head(tmp_path / "presets.vrm", "0.x")
    runner = CliRunner()
    for command in ("calibrate", "prepare"):
        result = runner.invoke(main, ["rig", command, str(vrm), "-o", str(tmp_path / "out")])
        assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
        assert "a VRM without ARKit morph targets" in result.output
    assert not (tmp_path / "out").exists()
