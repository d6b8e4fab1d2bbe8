"""Viseme exports: Oculus/OVRLipSync viseme curves and Rhubarb Lip Sync mouth cues.

The curves go through a morph :class:`PoseTable` from ARKit channels (by default the shipped
``oculus_visemes``). A pose cannot tell closed lips for /m/ from closed lips at rest, so when
the phones are known (``phones``), each consonant's frames take the viseme its articulatory
features name, in any language: Oculus ``PP`` for
bilabials, ``FF`` labiodentals, ``TH`` dentals, ``CH`` postalveolar and palatal fricatives and
affricates, ``SS`` other sibilants, ``nn`` other nasals and laterals, ``RR`` rhotic
approximants, ``DD`` other coronal stops, ``kk`` dorsal and glottal consonants (glides keep
the pose's); vowels and silences keep the pose's visemes.

Rhubarb cues, when the phones are known, come from the phones alone, one shape a phone by its
features as Rhubarb's own rules name them: ``A`` closed (bilabials), ``G`` labiodentals, ``H``
laterals, ``F`` rounded glides (/w/) and close or protruded rounded vowels (/u o y/), ``B``
every other consonant and the close unrounded vowels (/i/), ``E`` other rounded vowels (/ɔ ɝ ø/),
``D`` open back and central vowels (/ɑ a/), ``C`` the other open and mid vowels (/æ ɛ ʌ/), ``X``
silences and the time no phone covers; /h/ takes the next phone's shape. Without phones, or
with a pose table given, each frame takes the strongest shape of the table (by default the shipped
``rhubarb_shapes``).

- Oculus curves: 15 channels in OVRLipSync order ``sil PP FF TH DD kk CH SS nn RR aa E ih oh
  ou``, as CSV (``time`` in seconds, then the 15 values) or as vispeech animation JSON.
  A table's controls may use either spelling (``viseme_I``/``I``/``ih`` ...).
- Rhubarb cues: the phones' shapes (or the strongest shape of every frame), runs merged into
  cues, written exactly as Rhubarb writes TSV and JSON (times in seconds with 2 decimals,
  measured from the first frame; the TSV's last line holds the end time and ``X``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.formats.animation_json import write_animation_json
from vispeech.motion.rigging.retarget import PoseTable
from vispeech.motion.track import Track
from vispeech.phonetics.features import FEATURE_NAMES, phone_features

OCULUS_VISEMES = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
"""The 15 Oculus/Meta visemes in OVRLipSync index order."""

_OCULUS_BY_KEY = {v.lower(): v for v in OCULUS_VISEMES} | {"i": "ih", "o": "oh", "u": "ou"}


@dataclass(frozen=True)
class MouthCue:
    """One Rhubarb mouth cue: a shape held from ``start`` to ``end`` seconds."""

    start: float
    end: float
    value: str


def oculus_viseme(symbol: str, language: str) -> str | None:
    """The Oculus viseme a consonant's features name (see the module docstring); ``None`` for
    vowels, glides and silences."""
    f = dict(zip(FEATURE_NAMES, phone_features(symbol, language)))
    if f["vowel"] or f["silence"]:
        return None
    sibilant = f["fricative"] and (f["alveolar"] or f["retroflex"] or f["postalveolar"] or f["palatal"])
    for viseme, holds in (
        ("PP", f["bilabial"]),
        ("FF", f["labiodental"]),
        ("TH", f["dental"] and f["fricative"] and not f["stop"]),
        ("CH", (f["postalveolar"] or f["palatal"]) and f["fricative"]),
        ("SS", sibilant),
        ("nn", f["nasal"] or f["lateral"]),
        ("RR", f["approximant"] and (f["alveolar"] or f["retroflex"] or f["postalveolar"])),
        ("DD", f["stop"] and (f["alveolar"] or f["retroflex"] or f["dental"] or f["postalveolar"])),
        ("kk", (f["velar"] or f["glottal"] or f["palatal"]) and not f["approximant"]),
    ):
        if holds:
            return viseme
    return None


def rhubarb_shape(symbol: str, language: str) -> str | None:
    """The Rhubarb shape ``A`` ... ``H`` or ``X`` a phone's features name (see the module
    docstring); ``None`` for a glottal consonant (/h/), which takes the next phone's shape."""
    f = dict(zip(FEATURE_NAMES, phone_features(symbol, language)))
    if f["silence"] or f["pause"]:
        return "X"
    if f["vowel"]:
        if f["rounded"] >= 1 and (f["protruded"] >= 1 or f["open"] == 0):
            return "F"
        if f["open"] >= 1:
            return "C" if f["front"] >= 1 else "D"
        if f["rounded"] > 0:
            return "E"
        return "C" if f["open"] > 0 else "B"
    for shape, holds in (
        ("A", f["bilabial"]),
        ("G", f["labiodental"]),
        ("H", f["lateral"]),
        ("F", f["approximant"] and f["rounded"] >= 1),
        (None, f["glottal"] and not f["stop"]),
    ):
        if holds:
            return shape
    return "B"


def _phone_frames(track: Track, phones: PhoneSequence, name_of) -> list[tuple[np.ndarray, str]]:
    """``(frames, name)`` of every phone that ``name_of(symbol, language)`` names: the frames whose
    time lies in the phone (the nearest one for a phone shorter than a frame)."""
    times = track.times
    out = []
    for phone in phones:
        name = name_of(phone.symbol, phones.language)
        if name is None:
            continue
        frames = np.flatnonzero((times >= phone.start - TIME_TOLERANCE) & (times < phone.end - TIME_TOLERANCE))
        if not len(frames):
            nearest = int(round(((phone.start + phone.end) / 2 - track.start_time) * track.fps))
            frames = np.array([nearest]) if 0 <= nearest < track.n_frames else frames
        out.append((frames, name))
    return out


def oculus_visemes(track: Track, pose_table: PoseTable | None = None, phones: PhoneSequence | None = None) -> Track:
    """The 15 Oculus viseme curves of an ARKit ``track``, channels named as :data:`OCULUS_VISEMES`.

    With ``phones``, a consonant's frames give its viseme (see the module docstring) the frame's
    largest weight and ``sil`` none. Every frame's weights then sum to one, as OVRLipSync's do:
    ``sil`` is ``1 - Σ`` of the others, which are scaled down where their sum passes 1 (the
    table's controls are each clipped to [0, 1], so they may sum to more) and, in a
    consonant's frames, scaled to sum 1.
    """
    table = pose_table or PoseTable.load("oculus_visemes")
    visemes = table.apply(track)
    names = {}
    for control in visemes.channels:
        key = control.removeprefix("viseme_").lower()
        if key in _OCULUS_BY_KEY:
            names[_OCULUS_BY_KEY[key]] = control
    missing = [v for v in OCULUS_VISEMES if v not in names]
    if missing:
        raise VispeechError(f"pose table {table.name!r} has no control for viseme(s) {', '.join(missing)}")
    values = np.stack([visemes[names[v]] for v in OCULUS_VISEMES], axis=1)
    spoken = np.zeros(len(values), dtype=bool)
    if phones is not None:
        for frames, viseme in _phone_frames(track, phones, oculus_viseme):
            values[frames, OCULUS_VISEMES.index(viseme)] = values[frames].max(axis=1)
            spoken[frames] = True
    others = values[:, 1:]
    total = others.sum(axis=1)
    scale = np.where(total > 1.0, 1.0 / np.maximum(total, 1e-12), 1.0)
    scale[spoken & (total > 0)] = 1.0 / total[spoken & (total > 0)]
    others *= scale[:, None]
    values[:, 0] = np.clip(1.0 - others.sum(axis=1), 0.0, 1.0)
    return Track(values, OCULUS_VISEMES, track.fps, track.start_time)


def write_oculus_csv(
    track: Track, path: str | os.PathLike, pose_table: PoseTable | None = None, phones: PhoneSequence | None = None
) -> None:
    """Write the Oculus viseme curves as CSV: ``time,sil,PP,...,ou``, one row per frame (atomic)."""
    visemes = oculus_visemes(track, pose_table, phones)
    lines = [",".join(("time",) + OCULUS_VISEMES)]
    for t, row in zip(visemes.times, visemes.values):
        lines.append(",".join([f"{t:.6f}"] + [f"{v:.6f}" for v in row]))
    with atomic_output_file(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_oculus_json(
    track: Track, path: str | os.PathLike, pose_table: PoseTable | None = None, phones: PhoneSequence | None = None
) -> None:
    """Write the Oculus viseme curves as vispeech animation JSON (channels ``sil`` ... ``ou``)."""
    write_animation_json(oculus_visemes(track, pose_table, phones), path)


def mouth_cues(
    track: Track, pose_table: PoseTable | None = None, phones: PhoneSequence | None = None
) -> list[MouthCue]:
    """Rhubarb mouth cues, runs merged: with ``phones`` (and no ``pose_table``), each phone's shape
    over its time (see the module docstring); otherwise each frame's strongest shape in
    ``pose_table`` (default: the shipped ``rhubarb_shapes``).

    Times are seconds from the first frame, whose frame k covers ``[k / fps, (k + 1) / fps)``;
    boundaries are rounded to centiseconds as Rhubarb's are, and cues that round to nothing are dropped.
    """
    if phones is not None and pose_table is None:
        spans = _phone_spans(track, phones)
    else:
        table = pose_table or PoseTable.load("rhubarb_shapes")
        if table.kind != "morph":
            raise VispeechError(f"mouth cues need a morph pose table; {table.name!r} is a {table.kind} table")
        shapes = table.apply(track)
        spans = [
            (k / track.fps, (k + 1) / track.fps, shapes.channels[i]) for k, i in enumerate(shapes.values.argmax(1))
        ]
    cues: list[list] = []
    end_of_track = _duration(track)
    for start_s, end_s, label in spans:
        start, end = (round(min(max(t, 0.0), end_of_track) * 100) for t in (start_s, end_s))
        start = cues[-1][1] if cues else start  # the spans are contiguous; so are the cues
        if end <= start:
            continue
        if cues and cues[-1][2] == label:
            cues[-1][1] = end
        else:
            cues.append([start, end, label])
    return [MouthCue(start / 100, end / 100, label) for start, end, label in cues]


def _phone_spans(track: Track, phones: PhoneSequence) -> list[tuple[float, float, str]]:
    """``(start, end, shape)`` in seconds from the track's first frame: each phone's shape, ``X``
    where no phone is, through the track's end."""
    shapes = [rhubarb_shape(phone.symbol, phones.language) for phone in phones]
    for k in range(len(shapes) - 1, -1, -1):  # /h/ is shaped as what follows it
        if shapes[k] is None:
            shapes[k] = shapes[k + 1] if k + 1 < len(shapes) and shapes[k + 1] != "X" else "B"
    spans = []
    now = 0.0
    for phone, shape in zip(phones, shapes):
        start, end = phone.start - track.start_time, phone.end - track.start_time
        if start > now + TIME_TOLERANCE:
            spans.append((now, start, "X"))
        spans.append((start, end, str(shape)))
        now = max(now, end)
    spans.append((now, _duration(track), "X"))
    return spans


def write_rhubarb_tsv(
    track: Track, path: str | os.PathLike, pose_table: PoseTable | None = None, phones: PhoneSequence | None = None
) -> None:
    """Write mouth cues as Rhubarb's TSV: ``start<TAB>shape`` lines, then ``end<TAB>X``."""
    cues = mouth_cues(track, pose_table, phones)
    lines = [f"{cue.start:.2f}\t{cue.value}\n" for cue in cues]
    lines.append(f"{_duration(track):.2f}\tX\n")
    with atomic_output_file(path) as tmp:
        tmp.write_text("".join(lines), encoding="utf-8")


def write_rhubarb_json(
    track: Track,
    path: str | os.PathLike,
    pose_table: PoseTable | None = None,
    sound_file: str = "",
    phones: PhoneSequence | None = None,
) -> None:
    """Write mouth cues as Rhubarb's JSON, byte for byte in Rhubarb's layout."""
    cues = mouth_cues(track, pose_table, phones) or [MouthCue(0.0, 0.0, "X")]
    body = ",\n".join(
        f'    {{ "start": {c.start:.2f}, "end": {c.end:.2f}, "value": {json.dumps(c.value)} }}' for c in cues
    )
    text = (
        "{\n"
        '  "metadata": {\n'
        f'    "soundFile": {json.dumps(str(sound_file), ensure_ascii=False)},\n'
        f'    "duration": {_duration(track):.2f}\n'
        "  },\n"
        '  "mouthCues": [\n'
        f"{body}\n"
        "  ]\n"
        "}\n"
    )
    with atomic_output_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _duration(track: Track) -> float:
    return round(track.n_frames * 100 / track.fps) / 100
