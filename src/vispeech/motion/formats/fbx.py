"""FBX export for Unity, Maya and other FBX pipelines, made by Blender.

The track is first written as a glTF animation on the base model, its compression decoded
(:func:`vispeech.motion.formats.gltf.write_gltf_animation`); Blender, run headless (``blender -b``,
Debian's ``blender`` 3.4 or newer on the ``PATH``, or the ``BLENDER`` environment variable),
sets its scene to the track's frame rate and imports it with its own glTF importer, so that
every frame of the track lands on a whole FBX frame, and exports FBX with the shape-key
animation baked (blend shapes named as the morph targets, one animated channel each). Blender
is optional: without it, writing FBX is a one-line error naming what to install.
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.motion.track import Track

BLENDER_TIMEOUT_S = 600
"""The longest a Blender export may take."""

_SCRIPT = """\
import sys
import numpy
numpy.bool = bool  # Blender 3.4's glTF importer uses the alias numpy 1.24 removed
import bpy
glb, fbx, fps, base = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = int(fps), float(base)  # before the import, which keys seconds at it
bpy.ops.import_scene.gltf(filepath=glb)
ends = [a.frame_range[1] for a in bpy.data.actions]
scene.frame_start, scene.frame_end = 0, int(round(max(ends))) if ends else 0
bpy.ops.export_scene.fbx(filepath=fbx, bake_anim=True, bake_anim_use_all_bones=False, bake_anim_use_nla_strips=False,
                         bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True,
                         bake_anim_simplify_factor=0.0, add_leaf_bones=False, use_mesh_modifiers=False)
"""


def blender_path() -> str | None:
    """The Blender executable: ``$BLENDER`` if set, else ``blender`` on the ``PATH``."""
    return os.environ.get("BLENDER") or shutil.which("blender")


def write_fbx_animation(track: Track, base_glb: str | os.PathLike, out_path: str | os.PathLike) -> None:
    """Write ``base_glb``'s model with ``track`` as its shape-key animation to an FBX file, through Blender.

    Written atomically; raises :class:`VispeechError` when Blender is missing or fails.
    """
    blender = blender_path()
    if blender is None:
        raise VispeechError(
            "writing FBX needs Blender (apt-get install blender python3-numpy, or set BLENDER to its executable)"
        )
    fps = math.ceil(track.fps - 1e-9)  # Blender's rate is fps / fps_base: 29.97 = 30 / 1.001
    base = fps / track.fps
    with tempfile.TemporaryDirectory(prefix="vispeech-fbx-") as tmp:
        glb, script, fbx = Path(tmp) / "in.glb", Path(tmp) / "export.py", Path(tmp) / "out.fbx"
        write_gltf_animation(track, base_glb, glb, uncompressed=True)  # Blender cannot decode meshopt
        script.write_text(_SCRIPT, encoding="utf-8")
        try:
            with _terminated_as_interrupt():
                result = subprocess.run(
                    [
                        blender,
                        "-b",
                        "--factory-startup",
                        "--python-exit-code",
                        "1",
                        "--python",
                        str(script),
                        "--",
                        str(glb),
                        str(fbx),
                        str(fps),
                        repr(base),
                    ],
                    capture_output=True,
                    text=True,
                    timeout=BLENDER_TIMEOUT_S,
                )
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise VispeechError(f"Blender did not export FBX: {exc}") from None
        if result.returncode != 0 or not fbx.is_file():
            lines = [line for line in (result.stderr + result.stdout).splitlines() if "Error" in line]
            raise VispeechError(f"Blender did not export FBX: {(lines or ['exit code ' + str(result.returncode)])[-1]}")
        with atomic_output_file(out_path) as out:
            shutil.copyfile(fbx, out)


@contextmanager
def _terminated_as_interrupt() -> Iterator[None]:
    """While Blender runs, SIGTERM raises :class:`KeyboardInterrupt` (in the main thread; elsewhere
    nothing changes), so that ``subprocess.run`` kills Blender and the temporary folder is removed
    rather than both outliving a terminated process."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
