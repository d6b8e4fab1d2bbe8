"""The glTF (``--uncompressed``: Blender cannot decode meshopt) and FBX that ``vispeech convert
--glb`` writes open in Blender (Debian's ``blender``, headless) with their shape-key animation
equal to the track."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np

from conftest import require
from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.pipeline import speak, write_outputs

READ_SCENE = Path(__file__).parent / "blender" / "read_scene.py"


def _read_in_blender(blender: str, path: Path, out: Path) -> dict:
    result = subprocess.run([blender, "-b", "--factory-startup", "--python", str(READ_SCENE), "--", str(path), str(out)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and out.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    return json.loads(out.read_text())


def test_blender_imports_the_animated_head(tmp_path, shared_dir):
    blender = shutil.which("blender")
    require(blender, "Blender (apt-get install blender python3-numpy)")
    track = speak("My mom made a large map of the farm.", "en").track
    glb = tmp_path / "head.glb"
    write_gltf_animation(track, shared_dir / "assets" / "ict_head.glb", glb, uncompressed=True)  # as Blender needs
    found = _read_in_blender(blender, glb, tmp_path / "blender.json")

    (head,) = [o for o in found["objects"] if o["shape_keys"]]
    assert head["shape_keys"][0] == "Basis" and len(head["shape_keys"]) == 52
    assert "jawOpen" in head["shape_keys"] and "mouthClose" in head["shape_keys"]
    assert len(head["fcurves"]) == 51
    frames = np.arange(track.n_frames) / track.fps * found["fps"]  # Blender keys seconds at its scene rate
    for channel in ("jawOpen", "mouthClose", "mouthFunnel", "mouthPucker"):
        keys = np.array(head["fcurves"][f'key_blocks["{channel}"].value'])
        assert keys.shape == (track.n_frames, 2)
        np.testing.assert_allclose(keys[:, 0], frames, atol=1e-3)
        np.testing.assert_allclose(keys[:, 1], track[channel], atol=1e-6)
    assert np.ptp(np.array(head["fcurves"]['key_blocks["jawOpen"].value'])[:, 1]) > 0.1  # the mouth moves


def test_blender_imports_the_prepared_head_with_its_tongue(tmp_path, shared_dir):
    """The head `vispeech rig prepare` writes (tongue targets on one primitive, data-less zero
    targets on the others, vertex colours) animated: Blender reads the tongue shape keys and curves."""
    from vispeech.motion.rigging.head import prepare_head

    blender = shutil.which("blender")
    require(blender, "Blender (apt-get install blender python3-numpy)")
    track = speak("Ten good cats thank Linda.", "en").track
    prepare_head(shared_dir / "assets" / "ict_head.glb", tmp_path / "ready.glb")
    glb = tmp_path / "take.glb"
    write_gltf_animation(track, tmp_path / "ready.glb", glb, uncompressed=True)
    found = _read_in_blender(blender, glb, tmp_path / "blender.json")

    (head,) = [o for o in found["objects"] if o["shape_keys"]]
    assert len(head["shape_keys"]) == 56 and head["shape_keys"][-4:] == list(TONGUE_CHANNELS)
    for channel in ("tongueTipUp", "tongueBodyUp", "tongueOut", "jawOpen"):
        keys = np.array(head["fcurves"][f'key_blocks["{channel}"].value'])
        np.testing.assert_allclose(keys[:, 1], track[channel], atol=1e-6)
        assert keys[:, 1].max() > 0.2, channel  # it moves


def test_fbx_made_by_blender_carries_the_animation(tmp_path, shared_dir):
    from test_cli_say import run

    blender = shutil.which("blender")
    require(blender, "Blender (apt-get install blender python3-numpy)")
    utterance = speak("Bob met my mum at five.", "en")
    write_outputs(utterance, tmp_path / "said", scale="tracker")  # the track as the model made it
    fbx = tmp_path / "head.fbx"
    result = run("convert", str(tmp_path / "said" / "animation.json"), str(fbx), "--glb",
                 str(shared_dir / "assets" / "ict_head.glb"))
    assert result.exit_code == 0, result.output
    assert fbx.read_bytes()[:18] == b"Kaydara FBX Binary"
    found = _read_in_blender(blender, fbx, tmp_path / "fbx.json")
    (head,) = [o for o in found["objects"] if o["shape_keys"]]
    assert "jawOpen" in head["shape_keys"] and len(head["shape_keys"]) == 52
    track = utterance.track
    assert found["fps"] == track.fps  # the scene was set to the track's rate: one FBX frame per track frame
    keys = np.array(head["fcurves"]['key_blocks["jawOpen"].value'])
    frames = keys[:, 0] - keys[0, 0]
    np.testing.assert_allclose(frames[:track.n_frames], np.arange(track.n_frames), atol=1e-3)
    np.testing.assert_allclose(keys[:track.n_frames, 1], track["jawOpen"], atol=1e-3)


def test_fbx_without_blender_or_with_a_missing_base_model_is_one_error(tmp_path, monkeypatch):
    from test_cli_say import assert_clean_error, run

    write_outputs(speak("Hello.", "en"), tmp_path / "said")
    animation = str(tmp_path / "said" / "animation.json")
    missing = run("convert", animation, str(tmp_path / "a.fbx"), "--glb", str(tmp_path / "none.glb"))
    assert_clean_error(missing)
    assert "none.glb" in missing.output and not (tmp_path / "a.fbx").exists()
    monkeypatch.setenv("PATH", str(tmp_path))  # no blender here
    monkeypatch.delenv("BLENDER", raising=False)
    result = run("convert", animation, str(tmp_path / "a.fbx"))  # onto the shipped head
    assert_clean_error(result)
    assert "needs Blender" in result.output and not (tmp_path / "a.fbx").exists()


def test_a_terminated_fbx_export_takes_blender_and_its_files_with_it(tmp_path):
    """SIGTERM to `vispeech convert ... x.fbx` while Blender runs (a stand-in that sleeps): Blender
    is killed, its temporary folder removed, no FBX written."""
    import os
    import signal
    import sys
    import time

    write_outputs(speak("Hello.", "en"), tmp_path / "said")
    blender = tmp_path / "blender"
    blender.write_text(f"#!/bin/sh\necho $$ > {tmp_path / 'blender.pid'}\nexec sleep 60\n")
    blender.chmod(0o755)
    (tmp_path / "tmp").mkdir()
    env = {**os.environ, "BLENDER": str(blender), "TMPDIR": str(tmp_path / "tmp")}
    command = [str(Path(sys.executable).parent / "vispeech"), "convert", str(tmp_path / "said" / "animation.json"),
               str(tmp_path / "out.fbx")]
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while not (tmp_path / "blender.pid").exists() or not (tmp_path / "blender.pid").read_text().strip():
        assert process.poll() is None and time.monotonic() < deadline, process.stdout.read()
        time.sleep(0.05)
    pid = int((tmp_path / "blender.pid").read_text())
    process.send_signal(signal.SIGTERM)
    assert process.wait(30) != 0
    time.sleep(0.2)
    assert not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]
    assert os.listdir(tmp_path / "tmp") == [] and not (tmp_path / "out.fbx").exists()
