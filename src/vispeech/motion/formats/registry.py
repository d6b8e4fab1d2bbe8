"""Every track format by its one name, with its file extensions, its reader and its writer.

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
(vispeech animation JSON, which Oculus viseme JSON also is, or TalkingHead). ``csv`` is
accepted for ``livelink`` (:data:`ALIASES`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import read_json
from vispeech.limits import check_fps, check_track_range
from vispeech.motion.formats.animation_json import (
    ANIMATION_FORMAT,
    Animation,
    read_animation_json,
    read_talkinghead_json,
    write_animation_json,
    write_talkinghead_json,
)
from vispeech.motion.formats.livelink import (
    LIVELINK_CHANNELS,
    livelink_csv_texts,
    read_livelink_csv,
    write_livelink_csv,
)
from vispeech.motion.rigging.retarget import PoseTable
from vispeech.motion.track import Track


@dataclass(frozen=True)
class WriteOptions:
    """What a track file may carry besides the track; each format takes what it can hold."""

    phones: PhoneSequence | None = None
    audio: str | None = None
    base_glb: str | os.PathLike | None = None
    pose_table: PoseTable | None = None
    uncompressed: bool = False
    """Whether ``gltf`` decodes the base model's meshopt compression (for importers without it)."""


@dataclass(frozen=True)
class TrackFormat:
    """A track file format: its name, file extensions, writer and, if it can be read back, reader."""

    name: str
    extensions: tuple[str, ...]
    description: str
    writer: Callable[[Track, Path, WriteOptions], None]
    reader: Callable[[Path], Animation] | None = None
    maps_poses: bool = False
    """Whether a pose table is the format's own ARKit -> visemes/shapes table (else it retargets)."""

    @property
    def readable(self) -> bool:
        return self.reader is not None


_NO_LIVELINK = "the track has no Live Link Face channel (ARKit names, headYaw, ...) to write"


def _write_livelink(track: Track, path: Path, options: WriteOptions) -> None:
    if not set(track.channels) & set(LIVELINK_CHANNELS):
        raise VispeechError(_NO_LIVELINK)
    write_livelink_csv(track, path)


def livelink_texts(tracks: Sequence[Track]) -> list[bytes | VispeechError]:
    """What :func:`write_track` writes as ``livelink`` for each track, byte for byte, formatted
    together (:func:`~vispeech.motion.formats.livelink.livelink_csv_texts`): the file's bytes, or
    the :class:`VispeechError` that refuses the track."""
    usable = [bool(set(track.channels) & set(LIVELINK_CHANNELS)) for track in tracks]
    texts = iter(livelink_csv_texts([track for track, ok in zip(tracks, usable) if ok]))
    return [next(texts) if ok else VispeechError(_NO_LIVELINK) for ok in usable]


def _write_json(track: Track, path: Path, options: WriteOptions) -> None:
    write_animation_json(track, path, phones=options.phones, audio=options.audio)


def _write_talkinghead(track: Track, path: Path, options: WriteOptions) -> None:
    write_talkinghead_json(track, path)


def _write_oculus(track: Track, path: Path, options: WriteOptions) -> None:
    from vispeech.motion.formats.visemes import write_oculus_csv, write_oculus_json  # only for viseme files

    write = write_oculus_json if _is_json(path) else write_oculus_csv
    write(track, path, options.pose_table, options.phones)


def _write_rhubarb(track: Track, path: Path, options: WriteOptions) -> None:
    from vispeech.motion.formats.visemes import write_rhubarb_json, write_rhubarb_tsv  # only for mouth cues

    if _is_json(path):
        write_rhubarb_json(track, path, options.pose_table, sound_file=options.audio or "", phones=options.phones)
    else:
        write_rhubarb_tsv(track, path, options.pose_table, options.phones)


def _write_gltf(track: Track, path: Path, options: WriteOptions) -> None:
    base_glb = _base_glb(options)
    from vispeech.motion.formats.gltf import write_gltf_animation  # pygltflib: imported only for glTF

    write_gltf_animation(track, base_glb, path, uncompressed=options.uncompressed)


def _write_fbx(track: Track, path: Path, options: WriteOptions) -> None:
    base_glb = _base_glb(options)
    from vispeech.motion.formats.fbx import write_fbx_animation

    write_fbx_animation(track, base_glb, path)


def _base_glb(options: WriteOptions) -> str | os.PathLike:
    """The model a glTF or FBX file is written onto: the one given, else the shipped head."""
    if options.base_glb is None:
        from vispeech.motion.rigging.head import DEFAULT_HEAD  # the head's modules: imported only for glTF

        return DEFAULT_HEAD
    return options.base_glb


def _is_json(path: Path) -> bool:
    return path.name.lower().endswith(".json")


FORMATS: dict[str, TrackFormat] = {
    f.name: f
    for f in (
        TrackFormat(
            "livelink",
            (".csv",),
            "Live Link Face CSV",
            _write_livelink,
            lambda path: Animation(read_livelink_csv(path)),
        ),
        TrackFormat("json", (".json",), "vispeech animation JSON", _write_json, read_animation_json),
        TrackFormat(
            "talkinghead",
            (".talkinghead.json",),
            "TalkingHead blend-shape JSON",
            _write_talkinghead,
            lambda path: Animation(read_talkinghead_json(path)),
        ),
        TrackFormat(
            "oculus",
            (".visemes.csv", ".visemes.json"),
            "Oculus 15-viseme curves (CSV or JSON)",
            _write_oculus,
            maps_poses=True,
        ),
        TrackFormat(
            "rhubarb", (".tsv", ".rhubarb.json"), "Rhubarb mouth cues (TSV or JSON)", _write_rhubarb, maps_poses=True
        ),
        TrackFormat("gltf", (".glb",), "glTF 2.0 morph-target animation added to a base GLB", _write_gltf),
        TrackFormat("fbx", (".fbx",), "FBX of a base GLB's model with the animation (needs Blender)", _write_fbx),
    )
}
"""Every track format by name."""

ALIASES: dict[str, str] = {"csv": "livelink"}
"""Other names a format is accepted by: ``csv``, the name ``vispeech batch`` gave Live Link Face CSV."""


def format_name(name: str) -> str:
    """The format ``name`` names (itself or through :data:`ALIASES`); :class:`VispeechError`
    listing the known formats for any other."""
    name = ALIASES.get(name, name)
    if name not in FORMATS:
        raise VispeechError(f"unknown track format {name!r} (known formats: {', '.join(FORMATS)})")
    return name


def track_format(path: str | os.PathLike, fmt: str | None = None, *, reading: bool = False) -> str:
    """The format name for ``path``: ``fmt`` if given (checked), else from the extension.

    When ``reading`` a ``.json`` file, its content decides (vispeech animation JSON, which
    Oculus viseme JSON also is, TalkingHead, or Rhubarb). Raises :class:`VispeechError`
    listing the known formats.
    """
    if fmt is not None:
        name = format_name(fmt)
        suffix = Path(path).suffix.lower()
        kinds = {"." + ext.rsplit(".", 1)[-1] for f in FORMATS.values() for ext in f.extensions}
        own = {"." + ext.rsplit(".", 1)[-1] for ext in FORMATS[name].extensions}
        if suffix in kinds and suffix not in own:  # a .json that holds CSV would not read back
            raise VispeechError(f"{path}: a {name} file is {' or '.join(sorted(own))}, not {suffix}")
    else:
        lowered = Path(path).name.lower()
        matches = [(len(ext), f.name) for f in FORMATS.values() for ext in f.extensions if lowered.endswith(ext)]
        if not matches:
            raise VispeechError(
                f"cannot tell the track format of {path} from its extension (known formats: {', '.join(FORMATS)})"
            )
        name = max(matches)[1]
    if reading and fmt is None and _is_json(Path(path)):
        name = _json_kind(Path(path))
    if reading and not FORMATS[name].readable:
        readable = ", ".join(f.name for f in FORMATS.values() if f.readable)
        raise VispeechError(f"{name} files cannot be read as a track (readable formats: {readable})")
    return name


def read_animation(path: str | os.PathLike, fmt: str | None = None) -> Animation:
    """Read a track from ``path`` in format ``fmt`` (default: from the extension / content), with
    the phones and audio file name the file holds (vispeech animation JSON may hold them)."""
    reader = FORMATS[track_format(path, fmt, reading=True)].reader
    assert reader is not None  # track_format refuses formats that cannot be read
    return reader(Path(path))


def read_track(path: str | os.PathLike, fmt: str | None = None) -> Track:
    """Read a track from ``path`` in format ``fmt`` (default: from the extension / content)."""
    return read_animation(path, fmt).track


def write_track(
    track: Track,
    path: str | os.PathLike,
    fmt: str | None = None,
    *,
    phones: PhoneSequence | None = None,
    audio: str | None = None,
    base_glb: str | os.PathLike | None = None,
    pose_table: PoseTable | None = None,
    uncompressed: bool = False,
) -> None:
    """Write ``track`` to ``path`` in format ``fmt`` (default: from the extension), atomically.

    Parameters
    ----------
    phones, audio : stored by ``json`` (audio also as Rhubarb JSON's ``soundFile``); ``oculus``
        names each consonant's viseme by its features, ``rhubarb`` each phone's shape (unless
        given a ``pose_table``).
    base_glb : the model ``gltf`` and ``fbx`` add the animation to (default: the shipped head,
        :data:`~vispeech.motion.rigging.head.DEFAULT_HEAD`); the channels it has no morph
        target for are named in an :class:`~vispeech.errors.UnshownChannelsWarning`.
    pose_table : for ``oculus`` and ``rhubarb`` the ARKit -> visemes/shapes table that
        replaces the shipped one; for every other format a retargeting applied before writing.
    uncompressed : ``gltf`` decodes the base model's meshopt-compressed data (Blender, Maya and
        other importers without ``EXT_meshopt_compression``) instead of keeping it compressed.
    """
    path = Path(path)
    target = FORMATS[track_format(path, fmt)]
    if track.n_frames == 0:  # what no reader takes back
        raise VispeechError(f"cannot write {path}: the track has no frames")
    check_fps(track.fps, f"cannot write {path}: fps")
    # the values, and a start time that is a number (a format that keeps it checks its range)
    check_track_range(track.values, 0.0 if math.isfinite(track.start_time) else math.nan, f"cannot write {path}")
    if pose_table is not None and not target.maps_poses:
        track = pose_table.apply(track)
    target.writer(track, path, WriteOptions(phones, audio, base_glb, pose_table, uncompressed))


TEXT_FORMATS: tuple[str, ...] = ("livelink", "talkinghead", "oculus", "rhubarb")
"""The formats :func:`track_text` gives: those whose file is text and needs no base model."""


def track_text(track: Track, fmt: str, *, phones: PhoneSequence | None = None) -> str:
    """The text of ``track``'s file in format ``fmt`` (:data:`TEXT_FORMATS`; Oculus visemes as CSV,
    Rhubarb cues as TSV), as :func:`write_track` writes it with ``phones``: for a reply that
    carries the file rather than a link to it."""
    import tempfile

    name = format_name(fmt)
    if name not in TEXT_FORMATS:
        raise VispeechError(f"{name} is not a text format (text formats: {', '.join(TEXT_FORMATS)})")
    with tempfile.TemporaryDirectory(prefix="vispeech-") as folder:
        path = Path(folder) / f"track{FORMATS[name].extensions[0]}"
        write_track(track, path, name, phones=phones)
        return path.read_text(encoding="utf-8")


def _json_kind(path: Path) -> str:
    data = read_json(path)
    if data.get("format") == ANIMATION_FORMAT:
        return "json"
    if "dt" in data or isinstance(data.get("anim"), dict):
        return "talkinghead"
    if "mouthCues" in data:
        return "rhubarb"
    raise VispeechError(f"{path} is neither vispeech animation JSON nor TalkingHead JSON")
