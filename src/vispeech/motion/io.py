"""Reading and writing tracks in any supported format, chosen by name or by file extension.

============  ======================================  =====  ==========================================
format        extensions                              reads  what
============  ======================================  =====  ==========================================
livelink      ``.csv``                                yes    Live Link Face CSV
json          ``.json``                               yes    vispeech animation JSON
talkinghead   ``.talkinghead.json``                   yes    TalkingHead ``{"name", "dt", "vs"}``
oculus        ``.visemes.csv``, ``.visemes.json``     --     15 Oculus viseme curves (CSV or JSON)
rhubarb       ``.tsv``, ``.rhubarb.json``             --     Rhubarb mouth cues (TSV or JSON)
gltf          ``.glb``                                --     glTF morph-target animation on a base GLB
fbx           ``.fbx``                                --     the same as FBX, made by Blender
============  ======================================  =====  ==========================================

The longest matching extension wins; a ``.json`` file being read is recognised by its content
(vispeech animation JSON, which Oculus viseme JSON also is, or TalkingHead).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import read_json
from vispeech.motion.jsonformat import (
    ANIMATION_FORMAT,
    read_animation_json,
    read_talkinghead_json,
    write_animation_json,
    write_talkinghead_json,
)
from vispeech.motion.livelink import LIVELINK_CHANNELS, read_livelink_csv, write_livelink_csv
from vispeech.motion.rigging.retarget import PoseTable
from vispeech.motion.track import Track
from vispeech.motion.visemes import write_oculus_csv, write_oculus_json, write_rhubarb_json, write_rhubarb_tsv


@dataclass(frozen=True)
class TrackFormat:
    """A track file format: its name, file extensions and whether it can be read back."""

    name: str
    extensions: tuple[str, ...]
    description: str
    reader: Callable[[Path], Track] | None = None

    @property
    def readable(self) -> bool:
        return self.reader is not None


FORMATS: dict[str, TrackFormat] = {
    f.name: f
    for f in (
        TrackFormat("livelink", (".csv",), "Live Link Face CSV", read_livelink_csv),
        TrackFormat("json", (".json",), "vispeech animation JSON", lambda p: read_animation_json(p).track),
        TrackFormat("talkinghead", (".talkinghead.json",), "TalkingHead blend-shape JSON", read_talkinghead_json),
        TrackFormat("oculus", (".visemes.csv", ".visemes.json"), "Oculus 15-viseme curves (CSV or JSON)"),
        TrackFormat("rhubarb", (".tsv", ".rhubarb.json"), "Rhubarb mouth cues (TSV or JSON)"),
        TrackFormat("gltf", (".glb",), "glTF 2.0 morph-target animation added to a base GLB"),
        TrackFormat("fbx", (".fbx",), "FBX of a base GLB's model with the animation (needs Blender)"),
    )
}
"""Every track format by name."""


def track_format(path: str | os.PathLike, fmt: str | None = None, *, reading: bool = False) -> str:
    """The format name for ``path``: ``fmt`` if given (checked), else from the extension.

    When ``reading`` a ``.json`` file, its content decides (vispeech animation JSON, which
    Oculus viseme JSON also is, TalkingHead, or Rhubarb). Raises :class:`VispeechError`
    listing the known formats.
    """
    known = ", ".join(FORMATS)
    if fmt is not None:
        if fmt not in FORMATS:
            raise VispeechError(f"unknown track format {fmt!r} (known formats: {known})")
        name = fmt
    else:
        lowered = Path(path).name.lower()
        matches = [(len(ext), f.name) for f in FORMATS.values() for ext in f.extensions if lowered.endswith(ext)]
        if not matches:
            raise VispeechError(f"cannot tell the track format of {path} from its extension (known formats: {known})")
        name = max(matches)[1]
    if reading and fmt is None and Path(path).name.lower().endswith(".json"):
        name = _json_kind(Path(path))
    if reading and not FORMATS[name].readable:
        readable = ", ".join(f.name for f in FORMATS.values() if f.readable)
        raise VispeechError(f"{name} files cannot be read as a track (readable formats: {readable})")
    return name


def read_track(path: str | os.PathLike, fmt: str | None = None) -> Track:
    """Read a track from ``path`` in format ``fmt`` (default: from the extension / content)."""
    name = track_format(path, fmt, reading=True)
    return FORMATS[name].reader(Path(path))


def write_track(
    track: Track,
    path: str | os.PathLike,
    fmt: str | None = None,
    *,
    phones: PhoneSequence | None = None,
    audio: str | None = None,
    base_glb: str | os.PathLike | None = None,
    pose_table: PoseTable | None = None,
) -> None:
    """Write ``track`` to ``path`` in format ``fmt`` (default: from the extension), atomically.

    Parameters
    ----------
    phones, audio : stored by ``json`` (audio also as Rhubarb JSON's ``soundFile``); ``oculus``
        and ``rhubarb`` name each consonant's viseme or shape by its features.
    base_glb : the model ``gltf`` and ``fbx`` add the animation to (required for them).
    pose_table : for ``oculus`` and ``rhubarb`` the ARKit -> visemes/shapes table that
        replaces the shipped one; for every other format a retargeting applied before writing.
    """
    path = Path(path)
    name = track_format(path, fmt)
    if pose_table is not None and name not in ("oculus", "rhubarb"):
        track = pose_table.apply(track)
    as_json = path.name.lower().endswith(".json")
    if name == "livelink":
        if not set(track.channels) & set(LIVELINK_CHANNELS):
            raise VispeechError("the track has no Live Link Face channel (ARKit names, headYaw, ...) to write")
        write_livelink_csv(track, path)
    elif name == "json":
        write_animation_json(track, path, phones=phones, audio=audio)
    elif name == "talkinghead":
        write_talkinghead_json(track, path)
    elif name == "oculus":
        (write_oculus_json if as_json else write_oculus_csv)(track, path, pose_table, phones)
    elif name == "rhubarb":
        if as_json:
            write_rhubarb_json(track, path, pose_table, sound_file=audio or "", phones=phones)
        else:
            write_rhubarb_tsv(track, path, pose_table, phones)
    else:
        if base_glb is None:
            raise VispeechError(f"writing {'FBX' if name == 'fbx' else 'glTF'} needs a base model "
                                "(.glb with ARKit-named morph targets)")
        if name == "fbx":
            from vispeech.motion.fbx import write_fbx_animation

            write_fbx_animation(track, base_glb, path)
            return
        from vispeech.motion.gltf import write_gltf_animation  # pygltflib: imported only for glTF

        write_gltf_animation(track, base_glb, path)


def _json_kind(path: Path) -> str:
    data = read_json(path)
    if data.get("format") == ANIMATION_FORMAT:
        return "json"
    if "dt" in data or isinstance(data.get("anim"), dict):
        return "talkinghead"
    if "mouthCues" in data:
        return "rhubarb"
    raise VispeechError(f"{path} is neither vispeech animation JSON nor TalkingHead JSON")
