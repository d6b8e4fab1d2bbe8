"""The glTF that ``vispeech convert --glb`` writes opens in Blender (Debian's ``blender``, headless)
with its shape-key animation equal to the track."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np

from conftest import require
from vispeech.motion.gltf import write_gltf_animation
from vispeech.pipeline import speak

READ_GLTF = Path(__file__).parent / "blender" / "read_gltf.py"


def test_blender_imports_the_animated_head(tmp_path, shared_dir):
    blender = shutil.which("blender")
    require(blender, "Blender (apt-get install blender python3-numpy)")
    track = speak("My mom made a large map of the farm.", "en").track
    glb = tmp_path / "head.glb"
    write_gltf_animation(track, shared_dir / "assets" / "ict_head.glb", glb)
    out = tmp_path / "blender.json"
    result = subprocess.run([blender, "-b", "--factory-startup", "--python", str(READ_GLTF), "--", str(glb), str(out)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and out.is_file(), result.stdout[-2000:] + result.stderr[-2000:]
    found = json.loads(out.read_text())

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
