"""Property tests (hypothesis) for every reader: bad bytes give VispeechError, good files round-trip.

For each input format: arbitrary bytes, mutations of a valid file (cuts, flipped and inserted
bytes, numbers replaced by hostile ones) and structurally valid but wrong files (times
negative, out of order, overlapping; declared counts that differ from the content) must either
read or raise :class:`VispeechError` with a one-line message, never another exception.
Valid inputs read back as written.
"""

import json
import re
import struct
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vispeech import Track, VispeechError
from vispeech.alignment.formats import read_alignment, write_alignment
from vispeech.alignment.phones import Phone, PhoneSequence, Word
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.formats.animation_json import (
    read_animation_json,
    read_talkinghead_json,
    write_animation_json,
    write_talkinghead_json,
)
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.motion.formats.livelink import read_livelink_csv, write_livelink_csv
from vispeech.motion.formats.registry import read_track, write_track
from vispeech.motion.rigging.retarget import PoseTable

SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
TRACK = Track(np.linspace(0, 1, 6).reshape(3, 2), ("jawOpen", "mouthClose"), 30.0)
HELLO = PhoneSequence([Phone("sil", 0.0, 0.2), Phone("HH", 0.2, 0.3, 0), Phone("AH", 0.3, 0.5, 0, 1),
                       Phone("sil", 0.5, 0.7)], "en", [Word("huh", 0.2, 0.5)])
HOSTILE_NUMBERS = ["-1", "-0.5", "nan", "NaN", "inf", "-Infinity", "1e999", "9" * 400, "1e6", "0", "", "1.5.2"]


def glb_bytes() -> bytes:
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")
    blob = positions.tobytes() * 2
    gltf = pygltflib.GLTF2(
        scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0)],
        meshes=[pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0),
                                                               targets=[{"POSITION": 1}])],
                               extras={"targetNames": ["jawOpen"]})],
        accessors=[pygltflib.Accessor(bufferView=i, componentType=pygltflib.FLOAT, count=3, type="VEC3",
                                      min=[0, 0, 0], max=[1, 1, 0]) for i in range(2)],
        bufferViews=[pygltflib.BufferView(buffer=0, byteOffset=36 * i, byteLength=36) for i in range(2)],
        buffers=[pygltflib.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(blob)
    return b"".join(gltf.save_to_bytes())


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    """A valid file of every input format, by the file name it is read under."""
    folder = tmp_path_factory.mktemp("seeds")
    for name in ("a.TextGrid", "a.lab", "a.align", "a.json"):
        write_alignment(HELLO, folder / name)
    write_animation_json(TRACK, folder / "anim.json", phones=HELLO)
    write_livelink_csv(TRACK, folder / "take.csv")
    write_talkinghead_json(TRACK, folder / "th.talkinghead.json")
    (folder / "pose.json").write_text(json.dumps(
        {"type": "morph", "poses": {"viseme_aa": {"jawOpen": 0.6}, "viseme_PP": {"mouthClose": 0.8}},
         "rest": "viseme_sil", "range": [0, 1]}))
    (folder / "base.glb").write_bytes(glb_bytes())
    return {path.name: path.read_bytes() for path in folder.iterdir()}


def _glb_reader(path: Path):
    write_gltf_animation(TRACK, path, path.with_name("out.glb"))


READERS = {
    "a.TextGrid": read_alignment,
    "a.lab": read_alignment,
    "a.align": read_alignment,
    "a.json": read_alignment,
    "anim.json": read_animation_json,
    "take.csv": read_livelink_csv,
    "th.talkinghead.json": read_talkinghead_json,
    "pose.json": PoseTable.load,
    "base.glb": _glb_reader,
}
"""Each input format's reader, by the seed file it reads."""


def outcome(name: str, data: bytes, folder: Path) -> str:
    """``"ok"`` or ``"error"`` (a one-line VispeechError); any other exception fails the test."""
    path = folder / name
    path.write_bytes(data)
    try:
        READERS[name](path)
        if name.endswith(".json") or name.endswith(".csv"):
            read_track(path) if name != "pose.json" and name != "a.json" else None
        return "ok"
    except VispeechError as exc:
        message = str(exc)
        assert message and "\n" not in message and "Traceback" not in message, message
        return "error"


def mutate(data: bytes, draw) -> bytes:
    """One of: cut, flip a byte, insert bytes, duplicate a slice, replace a number."""
    kind = draw(st.sampled_from(["cut", "flip", "insert", "duplicate", "number", "number"]))
    n = len(data)
    if kind == "cut":
        return data[:draw(st.integers(0, n))]
    if kind == "flip":
        i = draw(st.integers(0, n - 1))
        return data[:i] + bytes([data[i] ^ draw(st.integers(1, 255))]) + data[i + 1:]
    if kind == "insert":
        i = draw(st.integers(0, n))
        return data[:i] + draw(st.binary(min_size=1, max_size=16)) + data[i:]
    if kind == "duplicate":
        i = draw(st.integers(0, n))
        j = draw(st.integers(i, min(n, i + 200)))
        return data[:j] + data[i:j] + data[j:]
    numbers = list(re.finditer(rb"-?\d+(?:\.\d+)?(?:e-?\d+)?", data))
    if not numbers:
        return data
    match = draw(st.sampled_from(numbers))
    return data[:match.start()] + draw(st.sampled_from(HOSTILE_NUMBERS)).encode() + data[match.end():]


@pytest.mark.parametrize("name", list(READERS))
def test_valid_seed_reads(seeds, tmp_path, name):
    assert outcome(name, seeds[name], tmp_path) == "ok"


@pytest.mark.parametrize("name", list(READERS))
@SETTINGS
@given(data=st.binary(max_size=600))
def test_arbitrary_bytes(seeds, tmp_path, name, data):
    outcome(name, data, tmp_path)


@pytest.mark.parametrize("name", list(READERS))
@SETTINGS
@given(draw=st.data())
def test_mutated_valid_files(seeds, tmp_path, name, draw):
    data = seeds[name]
    for _ in range(draw.draw(st.integers(1, 3))):
        data = mutate(data, draw.draw) or data
    outcome(name, data, tmp_path)


@pytest.mark.parametrize("name", ["a.json", "anim.json", "th.talkinghead.json", "pose.json"])
@SETTINGS
@given(depth=st.integers(1, 3000), opener=st.sampled_from(["[", '{"a":']))
def test_deep_json_never_recurses(seeds, tmp_path, name, depth, opener):
    closer = "]" if opener == "[" else "}"
    outcome(name, (opener * depth + "0" + closer * depth).encode(), tmp_path)


# --- structurally valid but wrong ----------------------------------------------------------------

TIMES = st.one_of(st.integers(-50, 900).map(lambda k: k / 100),
                  st.sampled_from([float("nan"), float("inf"), -0.0, 1e6]))


def _textgrid(intervals: list[tuple[float, float, str]], declared: int, end: float) -> str:
    lines = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "xmin = 0", f"xmax = {end!r}",
             "tiers? <exists>", "size = 1", "item []:", "    item [1]:", '        class = "IntervalTier"',
             '        name = "phones"', "        xmin = 0", f"        xmax = {end!r}",
             f"        intervals: size = {declared}"]
    for i, (start, stop, label) in enumerate(intervals, 1):
        lines += [f"        intervals [{i}]:", f"            xmin = {start!r}", f"            xmax = {stop!r}",
                  f'            text = "{label}"']
    return "\n".join(lines) + "\n"


def _well_formed(spans: list[tuple[float, float]], end: float | None = None) -> bool:
    """Times finite, non-negative, each span not empty and after the previous, all before ``end`` and 600 s."""
    previous = 0.0
    for start, stop in spans:
        if not (np.isfinite(start) and np.isfinite(stop)) or start < 0 or stop <= start or start < previous:
            return False
        previous = stop
    end = previous if end is None else end
    return bool(spans) and np.isfinite(end) and previous <= end <= 600


@SETTINGS
@given(spans=st.lists(st.tuples(TIMES, TIMES), min_size=1, max_size=6), extra=st.integers(-2, 2),
       labels=st.lists(st.sampled_from(["sil", "AH1", "HH", "M", ""]), min_size=6, max_size=6))
def test_textgrid_structure(tmp_path, spans, extra, labels):
    finite_ends = [s for pair in spans for s in pair if np.isfinite(s)]
    end = max([0.0, *finite_ends])
    declared = max(0, len(spans) + extra)
    text = _textgrid([(a, b, labels[i]) for i, (a, b) in enumerate(spans)], declared, end)
    expected = "ok" if _well_formed(spans, end) and declared == len(spans) else "error"
    assert outcome("a.TextGrid", text.encode(), tmp_path) == expected


@SETTINGS
@given(spans=st.lists(st.tuples(st.integers(-5, 40), st.integers(-5, 40)), min_size=1, max_size=6),
       suffix=st.sampled_from(["a.lab", "a.align"]))
def test_table_structure(tmp_path, spans, suffix):
    units = 1e7 if suffix == "a.lab" else 25000
    text = "".join(f"{a * 1000} {b * 1000} {'sil' if i % 2 else 'AH1'}\n" for i, (a, b) in enumerate(spans))
    # a pause of no length (sil at odd lines here) is dropped, as forced aligners write one at a clip's end
    kept = [(a, b) for i, (a, b) in enumerate(spans) if not (i % 2 and a == b >= 0)]
    seconds = [(a * 1000 / units, b * 1000 / units) for a, b in kept]
    assert outcome(suffix, text.encode(), tmp_path) == ("ok" if _well_formed(seconds) else "error")


@SETTINGS
@given(fps=st.one_of(st.floats(allow_nan=True, allow_infinity=False, width=32), st.integers(-5, 10 ** 6)),
       n_frames=st.integers(-1, 5), row=st.lists(st.floats(-2, 2), min_size=2, max_size=3))
def test_animation_json_structure(tmp_path, fps, n_frames, row):
    data = {"format": "vispeech-animation", "version": 1, "fps": fps, "start_time": 0, "n_frames": n_frames,
            "channels": ["jawOpen", "mouthClose"], "frames": [row] * 3}
    valid = 1 <= fps <= 240 and n_frames == 3 and len(row) == 2
    text = json.dumps(data)  # NaN is written as NaN, which the reader refuses
    assert outcome("anim.json", text.encode(), tmp_path) == ("ok" if valid else "error")


@SETTINGS
@given(cut=st.integers(0, 300), length_delta=st.integers(-64, 64), field=st.sampled_from([8, 12, "bin"]))
def test_glb_lengths(seeds, tmp_path, cut, length_delta, field):
    data = bytearray(seeds["base.glb"])
    if field == "bin":
        field = 20 + struct.unpack_from("<I", data, 12)[0]
    value = struct.unpack_from("<I", data, field)[0]
    struct.pack_into("<I", data, field, max(0, value + length_delta))
    data = bytes(data[:len(data) - cut])
    expected = "ok" if cut == 0 and length_delta == 0 else "error"
    assert outcome("base.glb", data, tmp_path) == expected


# --- round trips -------------------------------------------------------------------------------------

SYMBOLS = ["HH", "AH", "M", "P", "IY", "S", "T", "OW", "F", "V"]


@st.composite
def phone_sequences(draw) -> PhoneSequence:
    phones, t = [Phone("sil", 0.0, draw(st.integers(1, 30)) / 100)], None
    t = phones[0].end
    for symbol in draw(st.lists(st.sampled_from(SYMBOLS), min_size=1, max_size=8)):
        duration = draw(st.integers(4, 30)) / 100
        stress = draw(st.integers(0, 2)) if symbol in ("AH", "IY", "OW") else 0
        phones.append(Phone(symbol, round(t, 2), round(t + duration, 2), None, stress))
        t = round(t + duration, 2)
    phones.append(Phone("sil", t, round(t + 0.2, 2)))
    return PhoneSequence(phones, "en")


@pytest.mark.parametrize("suffix", [".TextGrid", ".lab", ".align", ".json"])
@SETTINGS
@given(phones=phone_sequences())
def test_alignment_round_trip(tmp_path, suffix, phones):
    write_alignment(phones, tmp_path / f"x{suffix}")
    back = read_alignment(tmp_path / f"x{suffix}")
    assert back.symbols == phones.symbols and back.language == "en"
    assert [p.stress for p in back] == [p.stress for p in phones]
    assert np.allclose(back.starts, phones.starts, atol=1e-4) and np.allclose(back.ends, phones.ends, atol=1e-4)


@SETTINGS
@given(n=st.integers(1, 150), fps=st.sampled_from([12.0, 15.0, 24.0, 25.0, 30.0, 60.0, 120.0, 144.0]),
       seed=st.integers(0, 99))
def test_track_round_trips(tmp_path, n, fps, seed):
    values = np.round(np.random.default_rng(seed).uniform(0, 1, (n, 3)), 6)
    track = Track(values, tuple(ARKIT_NAMES[:3]), fps)
    write_animation_json(track, tmp_path / "a.json")
    back = read_animation_json(tmp_path / "a.json").track
    assert back.channels == track.channels and back.fps == fps and np.array_equal(back.values, values)
    write_talkinghead_json(track, tmp_path / "a.talkinghead.json")
    back = read_talkinghead_json(tmp_path / "a.talkinghead.json")
    assert back.channels == track.channels and abs(back.fps - fps) < 1e-6 and np.allclose(back.values, values)
    write_livelink_csv(track, tmp_path / "a.csv")
    back = read_livelink_csv(tmp_path / "a.csv", fps=fps if n <= fps else None)  # shorter than 1 s: rate unknown
    assert back.fps == fps and np.allclose(back.select(track.channels).values, values, atol=1e-9)


WRITTEN_AS = {"livelink": "t.csv", "json": "t.json", "talkinghead": "t.talkinghead.json"}


@SETTINGS
@given(rows=st.lists(st.tuples(st.floats(allow_nan=False, allow_infinity=False),
                               st.floats(-2, 2)), min_size=1, max_size=4),
       start=st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.floats(359_999, 360_001)),
       fps=st.sampled_from([24.0, 30000 / 1001, 60.0]), fmt=st.sampled_from(sorted(WRITTEN_AS)))
def test_what_write_track_writes_read_track_reads(tmp_path, rows, start, fps, fmt):
    """Any finite track: written and read back as it was, or refused before a file is written."""
    track = Track(np.array(rows), ("jawOpen", "headYaw"), fps, start)
    path = tmp_path / WRITTEN_AS[fmt]
    path.unlink(missing_ok=True)
    try:
        write_track(track, path)
    except VispeechError as exc:
        assert str(exc).startswith(f"cannot write {path}") and not path.exists()
        return
    back = read_track(path).select(track.channels)
    assert np.allclose(back.values, track.values, rtol=0, atol=1e-6)
