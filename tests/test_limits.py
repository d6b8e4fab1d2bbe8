"""Limits (vispeech.limits) and the strict readers' refusals: one line naming what and where.

The command-line cases run the real ``vispeech`` entry point in a subprocess and check exit
code 2, exactly one stderr line starting ``error:``, and no traceback.
"""

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from vispeech import Track, VispeechError
from vispeech import limits
from vispeech.alignment.formats import read_alignment, write_alignment
from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.files import read_text
from vispeech.motion.formats.animation_json import read_animation_json, read_talkinghead_json, write_animation_json
from vispeech.motion.formats.gltf import write_gltf_animation
from vispeech.motion.formats.livelink import read_livelink_csv
from vispeech.motion.rigging.retarget import PoseTable
from vispeech.pipeline import animate, speak

HELLO = PhoneSequence([Phone("sil", 0.0, 0.2), Phone("HH", 0.2, 0.3), Phone("AH", 0.3, 0.5, stress=1),
                       Phone("sil", 0.5, 0.7)], "en")


def textgrid_text() -> str:
    return """File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 0.7
tiers? <exists>
size = 1
item []:
    item [1]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 0.7
        intervals: size = 3
        intervals [1]:
            xmin = 0
            xmax = 0.2
            text = "sil"
        intervals [2]:
            xmin = 0.2
            xmax = 0.5
            text = "AH1"
        intervals [3]:
            xmin = 0.5
            xmax = 0.7
            text = "sil"
"""


def tiny_glb(path: Path, *, cut: int | None = None) -> Path:
    """One triangle with a jawOpen morph target; ``cut`` keeps only the first bytes."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")
    blob = positions.tobytes() * 2
    views = [pygltflib.BufferView(buffer=0, byteOffset=36 * i, byteLength=36) for i in range(2)]
    accessors = [pygltflib.Accessor(bufferView=i, componentType=pygltflib.FLOAT, count=3, type="VEC3",
                                    min=[0, 0, 0], max=[1, 1, 0]) for i in range(2)]
    mesh = pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=0),
                                                          targets=[{"POSITION": 1}])],
                          extras={"targetNames": ["jawOpen"]})
    gltf = pygltflib.GLTF2(scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0)],
                           meshes=[mesh], accessors=accessors, bufferViews=views,
                           buffers=[pygltflib.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(blob)
    data = b"".join(gltf.save_to_bytes())
    path.write_bytes(data if cut is None else data[:cut])
    return path


# --- the limits themselves -------------------------------------------------------------------

@pytest.mark.parametrize("fps", [float("nan"), float("inf"), -1.0, 0.0, 0.5, 1e6, 241.0])
def test_fps_out_of_range(fps):
    with pytest.raises(VispeechError, match="fps"):
        limits.check_fps(fps)


@pytest.mark.parametrize("fps", [1.0, 24.0, 29.97, 60.0, 240.0])
def test_fps_in_range(fps):
    assert limits.check_fps(fps) == fps


def test_utterance_and_text_limits():
    limits.check_utterance(limits.MAX_DURATION_S, limits.MAX_PHONES)
    with pytest.raises(VispeechError, match="limit is 600 s"):
        limits.check_utterance(1e6, 3)
    with pytest.raises(VispeechError, match="phones"):
        limits.check_utterance(1.0, limits.MAX_PHONES + 1)
    with pytest.raises(VispeechError, match="characters"):
        limits.check_text("a" * (limits.MAX_TEXT_CHARS + 1))
    assert limits.check_text("Hällo 🙂") == "Hällo 🙂"
    with pytest.raises(VispeechError, match=r"lone surrogate U\+D83D at character 2$"):  # half an emoji
        limits.check_text("a\ud83d")


def test_track_range():
    values = np.array([[0.5, -limits.MAX_TRACK_VALUE], [limits.MAX_TRACK_VALUE, 0.0]])
    limits.check_track_range(values, -limits.MAX_START_TIME_S)
    with pytest.raises(VispeechError, match=r"^f.csv: frame 0, value 1 is -1e\+07: out of range"):
        limits.check_track_range(values * 10, 0.0, "f.csv")
    with pytest.raises(VispeechError, match="start time 360001 s is out of range"):
        limits.check_track_range(values, limits.MAX_START_TIME_S + 1)
    with pytest.raises(VispeechError, match="start time nan s"):
        limits.check_track_range(values, float("nan"))


def test_pipeline_refuses_before_work():
    long = PhoneSequence([Phone("sil", 0.0, 0.2), Phone("AH", 0.2, 1e6)], "en")
    with pytest.raises(VispeechError, match="600 s"):
        animate(long, "baseline")
    with pytest.raises(VispeechError, match="fps"):
        animate(HELLO, "baseline", float("nan"))
    with pytest.raises(VispeechError, match="characters"):
        speak("a" * (limits.MAX_TEXT_CHARS + 1))


@pytest.mark.parametrize("text,message", [
    ("[" * 100 + "]" * 100, "nested 100 levels"),
    ('{"a": NaN}', "non-finite number NaN"),
    ('{"a": -Infinity}', "non-finite number -Infinity"),
    ('{"a": 1e999}', "out of range"),
    ('{"a": ' + "9" * 400 + "}", "integer of 400 digits"),
    ('{"a": [1, 2', "not valid JSON"),
])
def test_parse_json_refuses(text, message):
    with pytest.raises(VispeechError, match=message):
        limits.parse_json(text, "x.json")


def test_json_depth_ignores_brackets_in_strings():
    assert limits.json_depth('{"a": "[[[[[[{{{{"}')[0] == 1
    assert limits.parse_json('{"a": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["}', "x") == {"a": "[" * 42}


# --- reading files -----------------------------------------------------------------------------

def test_read_text_refuses_what_is_not_a_regular_file(tmp_path):
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    with pytest.raises(VispeechError, match="not a regular file"):
        read_text(tmp_path / "zero.json")
    os.mkfifo(tmp_path / "fifo.lab")
    with pytest.raises(VispeechError, match="not a regular file"):
        read_text(tmp_path / "fifo.lab")
    (tmp_path / "folder.TextGrid").mkdir()
    with pytest.raises(VispeechError, match="is a folder"):
        read_text(tmp_path / "folder.TextGrid")


def test_read_text_size_limit_and_encodings(tmp_path):
    (tmp_path / "big.lab").write_text("0 100 sil\n" * 100)
    with pytest.raises(VispeechError, match="the limit is 100"):
        read_text(tmp_path / "big.lab", limit=100)
    (tmp_path / "odd.lab").write_bytes(b"\xff\xfe" + "0 1 sil\n".encode("utf-16-le") + b"x")
    with pytest.raises(VispeechError, match="odd number of bytes"):
        read_text(tmp_path / "odd.lab")
    (tmp_path / "surrogate.lab").write_bytes(b"\xff\xfe" + b"\x00\xd8" + b"a\x00")
    with pytest.raises(VispeechError, match="not valid UTF-16"):
        read_text(tmp_path / "surrogate.lab")
    (tmp_path / "binary.lab").write_bytes(b"\x7fELF\x02\x01\x01\x00\x00")
    with pytest.raises(VispeechError, match="NUL byte at byte 7"):
        read_text(tmp_path / "binary.lab")
    (tmp_path / "even.lab").write_bytes("\ufeff0 1 sil\n".encode("utf-16-le"))
    assert read_text(tmp_path / "even.lab").strip() == "0 1 sil"


@pytest.mark.parametrize("old,new,message", [
    ("xmin = 0.2\n            xmax = 0.5", "xmin = -0.2\n            xmax = 0.5", r"line 20: .*-0.2 is negative"),
    ("intervals: size = 3", "intervals: size = 8", "declares 8 intervals but holds 3"),
    ("intervals: size = 3", "intervals: size = 2", "holds more intervals than the 2 it declares"),
    ("xmin = 0.2\n            xmax = 0.5", "xmin = 0.1\n            xmax = 0.5", "line 20: .*before the previous"),
    ("xmin = 0.5\n            xmax = 0.7", "xmin = 0.5\n            xmax = 0.4", "line 24: .*not after its start"),
    ("xmax = 0.5", "xmax = nan", "not a finite number"),
    ("xmax = 0.5", "xmax = 1e999", "not a finite number"),
    ("size = 1\n", "size = 2\n", "declares 2 tiers but holds 1"),
    ("xmax = 0.7\ntiers", "xmax = 0.6\ntiers", "outside the grid"),
    ("xmax = 0.7\ntiers", "xmax = 1e6\ntiers", "limit of 600 s"),
    ("xmin = 0.2\n            xmax = 0.5", "xmin = 0.1999999\n            xmax = 0.5", "line 20: .*before the previous"),
])
def test_textgrid_strict(tmp_path, old, new, message):
    text = textgrid_text()
    assert old in text
    (tmp_path / "bad.TextGrid").write_text(text.replace(old, new, 1))
    with pytest.raises(VispeechError, match=message):
        read_alignment(tmp_path / "bad.TextGrid")


def test_textgrid_tier_names_are_unique(tmp_path):
    text = textgrid_text().replace("size = 1\n", "size = 2\n")
    tier = text[text.index("    item [1]:"):]
    (tmp_path / "twice.TextGrid").write_text(text + tier.replace("item [1]", "item [2]"))
    with pytest.raises(VispeechError, match=r"line 28: tier 2 has the name of an earlier one \('phones'\)"):
        read_alignment(tmp_path / "twice.TextGrid")
    (tmp_path / "two.TextGrid").write_text(text + tier.replace("item [1]", "item [2]").replace('"phones"', '"words"'))
    assert read_alignment(tmp_path / "two.TextGrid").symbols == ["sil", "AH", "sil"]


def test_textgrid_times_as_praat_may_write_them(tmp_path):
    text = textgrid_text().replace("xmin = 0.2\n            xmax = 0.5", "xmin = 2e-1\n            xmax = 5.0E-1")
    (tmp_path / "e.TextGrid").write_text(text)
    assert [(p.start, p.end) for p in read_alignment(tmp_path / "e.TextGrid")] == [(0, 0.2), (0.2, 0.5), (0.5, 0.7)]


def test_textgrid_good_and_short_form(tmp_path):
    (tmp_path / "good.TextGrid").write_text(textgrid_text())
    assert read_alignment(tmp_path / "good.TextGrid").symbols == ["sil", "AH", "sil"]
    write_alignment(HELLO, tmp_path / "hello.TextGrid")
    from praatio import textgrid
    grid = textgrid.openTextgrid(str(tmp_path / "hello.TextGrid"), includeEmptyIntervals=True)
    grid.save(str(tmp_path / "short.TextGrid"), format="short_textgrid", includeBlankSpaces=True)
    assert read_alignment(tmp_path / "short.TextGrid").symbols == HELLO.symbols


@pytest.mark.parametrize("text,message", [
    ("-5 100 sil\n", "line 1: negative time -5"),
    ("0 100 sil\n50 200 AH1\n", "line 2: the span starts at 50, before the previous one ends"),
    ("0 100 sil\n100 100 AH1\n", "line 2: the span ends at 100, not after its start"),
    ("0 100 sil\n100 " + "9" * 400 + " AH1\n", "line 2: expected 'start end label'"),
    ("0 100 sil\n100 250000000000000 AH1\n", "line 2: time .* past the limit of 600 s"),
    ("0 1.5 sil\n", "line 1: expected 'start end label' \\(integer times\\)"),
])
def test_lab_strict(tmp_path, text, message):
    (tmp_path / "bad.lab").write_text(text)
    with pytest.raises(VispeechError, match=message):
        read_alignment(tmp_path / "bad.lab")


def test_json_alignment_limits(tmp_path):
    data = {"format": "vispeech-phones", "version": 1, **HELLO.to_dict()}
    data["phones"][1]["end"] = 1e6
    data["phones"][2]["start"] = 1e6
    data["phones"][2]["end"] = 1e6 + 1
    (tmp_path / "long.json").write_text(json.dumps(data))
    with pytest.raises(VispeechError, match="600 s"):
        read_alignment(tmp_path / "long.json")
    (tmp_path / "nan.json").write_text(json.dumps({**data, "phones": [{"symbol": "sil", "start": float("nan"),
                                                                       "end": 1}]}))
    with pytest.raises(VispeechError, match="non-finite number NaN"):
        read_alignment(tmp_path / "nan.json")


def test_track_readers_strict(tmp_path):
    track = Track(np.full((3, 1), 0.5), ("jawOpen",), 30.0)
    write_animation_json(track, tmp_path / "a.json")
    data = json.loads((tmp_path / "a.json").read_text())
    (tmp_path / "fast.json").write_text(json.dumps({**data, "fps": 1e6}))
    with pytest.raises(VispeechError, match="fps must be between 1 and 240"):
        read_animation_json(tmp_path / "fast.json")
    (tmp_path / "text.json").write_text(json.dumps({**data, "frames": [["x"], [0.1], [0.2]]}))
    with pytest.raises(VispeechError, match="frame 0, value 0 is not a number"):
        read_animation_json(tmp_path / "text.json")
    (tmp_path / "th.json").write_text(json.dumps({"dt": [1e-6, 1e-6], "vs": {"jawOpen": [0, 1]}}))
    with pytest.raises(VispeechError, match="frame rate"):
        read_talkinghead_json(tmp_path / "th.json")
    (tmp_path / "long.json").write_text(json.dumps({"dt": [1e300, 1e300], "vs": {"jawOpen": [0, 1]}}))
    with pytest.raises(VispeechError):
        read_talkinghead_json(tmp_path / "long.json")
    (tmp_path / "nan.csv").write_text("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,nan\n")
    with pytest.raises(VispeechError, match="line 2: JawOpen is nan, not a finite number"):
        read_livelink_csv(tmp_path / "nan.csv")
    (tmp_path / "tc.csv").write_text("Timecode,BlendshapeCount,JawOpen\n00:00:00:" + "9" * 400 + ",1,0\n")
    with pytest.raises(VispeechError, match="line 2: bad timecode"):
        read_livelink_csv(tmp_path / "tc.csv")
    (tmp_path / "blank.csv").write_text("Timecode,BlendshapeCount,,JawOpen\n00:00:00:00,1,0,0\n")
    with pytest.raises(VispeechError, match="line 1: column 3 has no name"):
        read_livelink_csv(tmp_path / "blank.csv")
    (tmp_path / "pose.json").write_text('{"type": "morph", "poses": {"a": {"jawOpen": 1e300}, '
                                        '"b": {"mouthClose": 1e300}}}')
    with pytest.raises(VispeechError, match="too large"):
        PoseTable.load(tmp_path / "pose.json")
    (tmp_path / "deep.json").write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(VispeechError, match="nested 5000 levels"):
        PoseTable.load(tmp_path / "deep.json")


def test_glb_cut_short_or_lying_is_refused(tmp_path):
    track = Track(np.full((3, 1), 0.5), ("jawOpen",), 30.0)
    good = tiny_glb(tmp_path / "base.glb")
    write_gltf_animation(track, good, tmp_path / "out.glb")
    size = good.stat().st_size
    with pytest.raises(VispeechError, match="declares .* bytes but the file has"):
        write_gltf_animation(track, tiny_glb(tmp_path / "half.glb", cut=size // 2), tmp_path / "x.glb")
    with pytest.raises(VispeechError, match="not a binary glTF"):
        write_gltf_animation(track, tiny_glb(tmp_path / "tiny.glb", cut=10), tmp_path / "x.glb")
    data = bytearray(good.read_bytes())
    json_length = struct.unpack_from("<I", data, 12)[0]
    bin_header = 20 + json_length
    struct.pack_into("<I", data, bin_header, 10 ** 6)  # the BIN chunk claims more than the file holds
    (tmp_path / "chunk.glb").write_bytes(bytes(data))
    with pytest.raises(VispeechError, match=f"byte {bin_header}: chunk 1 declares 1000000 bytes"):
        write_gltf_animation(track, tmp_path / "chunk.glb", tmp_path / "x.glb")
    gltf = json.loads(bytes(data[20:20 + json_length]))
    gltf["buffers"][0]["byteLength"] = 10 ** 6
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    blob = good.read_bytes()[20 + json_length + 8:]
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\x00") + blob
    (tmp_path / "buffer.glb").write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    with pytest.raises(VispeechError, match="byteLength is 1000000 but the BIN chunk holds 72"):
        write_gltf_animation(track, tmp_path / "buffer.glb", tmp_path / "x.glb")
    assert not (tmp_path / "x.glb").exists()


# --- the command line --------------------------------------------------------------------------

def run_cli(*args: str) -> subprocess.CompletedProcess:
    script = "import sys; from vispeech.cli import main; sys.argv[0] = 'vispeech'; main()"
    return subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=60)


def assert_one_error_line(result: subprocess.CompletedProcess, *needles: str) -> None:
    lines = result.stderr.splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    for needle in needles:
        assert needle in lines[0]


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bad")
    (folder / "negative.TextGrid").write_text(textgrid_text().replace("xmin = 0.2", "xmin = -0.2", 1))
    (folder / "count.TextGrid").write_text(textgrid_text().replace("size = 3", "size = 8"))
    (folder / "long.lab").write_text("0 10000000000000 sil\n")
    (folder / "odd.lab").write_bytes(b"\xff\xfe" + "0 1 sil\n".encode("utf-16-le") + b"x")
    (folder / "deep.json").write_text("[" * 100000 + "]" * 100000)
    (folder / "digits.json").write_text('{"format": "vispeech-animation", "fps": ' + "9" * 400 + "}")
    (folder / "zero.csv").symlink_to("/dev/zero")
    (folder / "garbage.csv").write_bytes(bytes(range(256)) * 4)
    (folder / "huge.csv").write_text("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,1e308\n")
    good = {"format": "vispeech-animation", "version": 1, "fps": 30, "channels": ["jawOpen"], "frames": [[0.5]]}
    (folder / "late.json").write_text(json.dumps({**good, "start_time": 1e306}))
    (folder / "good.TextGrid").write_text(textgrid_text())
    write_animation_json(Track(np.full((3, 1), 0.5), ("jawOpen",), 30.0), folder / "good.json")
    tiny_glb(folder / "half.glb", cut=200)
    (folder / "folder.json").mkdir()
    (folder / "folder.glb").mkdir()
    os.mkfifo(folder / "fifo.TextGrid")
    return folder


@pytest.mark.parametrize("args,needle", [
    (["animate-phones", "{d}/negative.TextGrid", "-o", "{d}/out"], "is negative"),
    (["animate-phones", "{d}/count.TextGrid", "-o", "{d}/out"], "declares 8 intervals but holds 3"),
    (["animate-phones", "{d}/long.lab", "-o", "{d}/out"], "600 s"),
    (["animate-phones", "{d}/odd.lab", "-o", "{d}/out"], "odd number of bytes"),
    (["animate-phones", "{d}/deep.json", "-o", "{d}/out"], "nested 100000 levels"),
    (["animate-phones", "{d}/good.TextGrid", "--fps", "nan", "-o", "{d}/out"], "--fps"),
    (["animate-phones", "{d}/good.TextGrid", "--fps", "1e6", "-o", "{d}/out"], "--fps"),
    (["say", "Hello", "--fps", "inf", "-o", "{d}/out"], "--fps"),
    (["say", "Hello", "--fps", "1e6", "-o", "{d}/out"], "--fps"),
    (["say", "a" * 10001, "-o", "{d}/out"], "characters"),
    (["say", "Hello \udcff world", "-o", "{d}/out"], "lone surrogate U+DCFF at character 7 (the byte 0xff"),
    (["convert", "{d}/huge.csv", "{d}/x.json"], "line 2: JawOpen is 1e308, not a finite number within"),
    (["convert", "{d}/late.json", "{d}/x.csv"], "start time 1e+306 s is out of range"),
    (["convert", "{d}/digits.json", "{d}/x.csv"], "integer of 400 digits"),
    (["convert", "{d}/zero.csv", "{d}/x.json"], "not a regular file"),
    (["convert", "{d}/garbage.csv", "{d}/x.json"], "NUL byte"),
    (["convert", "{d}/good.json", "{d}/x.csv", "--fps", "nan"], "--fps"),
    (["convert", "{d}/good.json", "{d}/x.glb", "--glb", "{d}/half.glb"], "cut short"),
    (["convert", "{d}/good.json", "{d}/x.csv", "--pose-table", "{d}/deep.json"], "nested"),
    (["convert", "{d}/folder.json", "{d}/x.csv"], "is a folder"),
    (["convert", "{d}/good.json", "{d}/x.glb", "--glb", "{d}/folder.glb"], "is a folder"),
    (["animate-phones", "{d}/fifo.TextGrid", "-o", "{d}/out"], "not a regular file"),
])
def test_cli_bad_input_one_error_line(bad_files, args, needle):
    result = run_cli(*(a.format(d=bad_files) for a in args))
    assert_one_error_line(result, needle)
    assert not (bad_files / "out").exists() and not (bad_files / "x.csv").exists()
