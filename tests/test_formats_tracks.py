"""Track files: vispeech JSON, TalkingHead JSON, Oculus visemes, Rhubarb cues, format dispatch."""

import json
from pathlib import Path

import numpy as np
import pytest

import vispeech.motion.rigging
from vispeech import Phone, PhoneSequence, Track, VispeechError, Word
from vispeech.motion.formats.animation_json import (
    read_animation_json,
    read_talkinghead_json,
    write_animation_json,
    write_talkinghead_json,
)
from vispeech.motion.formats.registry import FORMATS, read_animation, read_track, track_format, write_track
from vispeech.motion.formats.visemes import OCULUS_VISEMES, MouthCue, mouth_cues, oculus_visemes
from vispeech.motion.rigging.retarget import PoseTable

DATA = Path(vispeech.motion.rigging.__file__).parent / "data"


def poses(table: str) -> dict:
    return json.loads((DATA / f"{table}.json").read_text())["poses"]


def pose_track(frames: list[dict], fps: float) -> Track:
    """A track whose frames are the given ARKit poses ({} = rest)."""
    channels = sorted({c for f in frames for c in f}) or ["jawOpen"]
    return Track(np.array([[f.get(c, 0.0) for c in channels] for f in frames]), channels, fps)


def small_track(fps=30.0, n=12, start=0.0) -> Track:
    rng = np.random.default_rng(4)
    return Track(np.round(rng.uniform(0, 1, (n, 3)), 6), ("jawOpen", "mouthClose", "mouthFunnel"), fps, start)


def test_animation_json_round_trip_with_phones_and_audio(tmp_path):
    phones = PhoneSequence([Phone("sil", 0, 0.1), Phone("M", 0.1, 0.3, 0), Phone("sil", 0.3, 0.4)], "en",
                           [Word("mm", 0.1, 0.3)])
    track = small_track(start=0.5)
    write_animation_json(track, tmp_path / "a.json", phones=phones, audio="a.wav")
    data = json.loads((tmp_path / "a.json").read_text())
    assert data["format"] == "vispeech-animation" and data["version"] == 1 and data["n_frames"] == 12
    back = read_animation_json(tmp_path / "a.json")
    assert back.track.channels == track.channels and back.track.fps == 30.0 and back.track.start_time == 0.5
    assert np.array_equal(back.track.values, track.values)
    assert back.phones == phones and back.audio == "a.wav"


@pytest.mark.parametrize("change,message", [
    ({"format": "other"}, "not a vispeech-animation file"),
    ({"version": 2}, "unsupported vispeech-animation version"),
    ({"fps": None}, "missing 'fps'"),
    ({"frames": [[0.1, 0.2], [0.3]]}, "frame 1 does not have 2 values"),
    ({"n_frames": 5}, "n_frames is 5"),
    ({"fps": -1}, "fps must be positive"),
    ({"frames": []}, "non-empty lists"),
    ({"channels": [], "frames": [[]], "n_frames": 1}, "non-empty lists"),
    ({"channels": [5, "mouthClose"]}, "a channel's name must be non-empty text, got 5"),
    ({"channels": ["", "mouthClose"]}, "a channel's name must be non-empty text, got ''"),
])
def test_animation_json_errors(tmp_path, change, message):
    data = {"format": "vispeech-animation", "version": 1, "fps": 30, "start_time": 0, "n_frames": 2,
            "channels": ["jawOpen", "mouthClose"], "frames": [[0.1, 0.2], [0.3, 0.4]]}
    data = {k: v for k, v in (data | change).items() if v is not None}
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(VispeechError, match=message):
        read_animation_json(tmp_path / "bad.json")


@pytest.mark.parametrize("name", ["t.csv", "t.json", "t.talkinghead.json"])
def test_writers_refuse_what_their_readers_refuse(tmp_path, name):
    huge = Track(np.array([[0.5], [1e308]]), ("jawOpen",), 30.0)
    with pytest.raises(VispeechError, match=f"^cannot write {tmp_path / name}: frame 1, value 0 is 1e"):
        write_track(huge, tmp_path / name)
    assert not (tmp_path / name).exists()
    late = small_track(start=1e306)
    if name == "t.talkinghead.json":  # holds no start time
        write_track(late, tmp_path / name)
        assert read_track(tmp_path / name).start_time == 0.0
    else:
        with pytest.raises(VispeechError, match="start time 1e\\+306 s is out of range"):
            write_track(late, tmp_path / name)
        assert not (tmp_path / name).exists()


def test_animation_json_phones_are_checked_both_ways(tmp_path):
    phones = PhoneSequence([Phone("sil", 0, 0.1), Phone("AA", 0.1, 0.3, None, 7)], "en")
    with pytest.raises(VispeechError, match="cannot write .*phone 1 \\(AA\\) has stress 7"):
        write_animation_json(small_track(), tmp_path / "a.json", phones=phones)
    data = {"format": "vispeech-animation", "version": 1, **small_track().to_dict(), "phones": phones.to_dict()}
    (tmp_path / "a.json").write_text(json.dumps(data))
    with pytest.raises(VispeechError, match="a.json: phones: phone 1 \\(AA\\) has stress 7"):
        read_animation_json(tmp_path / "a.json")
    # read as the alignment readers read phones: a symbol the language lacks, a word index that is
    # no whole number, phones out of order
    for phone, message in (({"symbol": "XX"}, "phone 1 at 0.100 s: unknown phone symbol 'XX' for language en"),
                           ({"word": 0.5}, "0.5 is not a whole number"), ({"word": True}, "True is not a whole"),
                           ({"start": 0.05}, "before the previous phone ends")):
        data["phones"]["phones"][1] = {**phones.to_dict()["phones"][1], "stress": 1, **phone}
        (tmp_path / "a.json").write_text(json.dumps(data))
        with pytest.raises(VispeechError, match=message):
            read_animation_json(tmp_path / "a.json")


def test_not_json_and_empty(tmp_path):
    (tmp_path / "x.json").write_text("{oops")
    with pytest.raises(VispeechError, match="not valid JSON"):
        read_track(tmp_path / "x.json")
    (tmp_path / "e.json").write_text("")
    with pytest.raises(VispeechError, match="empty"):
        read_track(tmp_path / "e.json")


def test_talkinghead_round_trip(tmp_path):
    track = small_track(fps=30.0)
    write_talkinghead_json(track, tmp_path / "t.json")
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["name"] == "blendshapes" and len(data["dt"]) == 12 and data["dt"][0] == pytest.approx(1000 / 30)
    assert data["vs"]["jawOpen"] == track["jawOpen"].tolist()
    back = read_talkinghead_json(tmp_path / "t.json")
    assert back.fps == 30.0 and back.channels == track.channels and np.array_equal(back.values, track.values)


def test_talkinghead_wrapped_and_uneven_dt(tmp_path):
    anim = {"anim": {"name": "blendshapes", "dt": [100, 100, 200, 100], "vs": {"jawOpen": [0.0, 0.2, 0.4, 0.0]}}}
    (tmp_path / "t.json").write_text(json.dumps(anim))
    track = read_track(tmp_path / "t.json")  # recognised by content
    assert track.fps == 10.0 and track.n_frames == 5
    assert np.allclose(track["jawOpen"], [0.0, 0.2, 0.4, 0.2, 0.0])
    anim["anim"]["vs"]["jawOpen"] = [0.1]
    (tmp_path / "t.json").write_text(json.dumps(anim))
    with pytest.raises(VispeechError, match="1 values for 4 frames"):
        read_track(tmp_path / "t.json", "talkinghead")


def test_oculus_viseme_curves(tmp_path):
    table = poses("oculus_visemes")
    frames = [{}, table["viseme_PP"], table["viseme_aa"], table["viseme_I"], table["viseme_U"]]
    track = pose_track(frames, fps=25)
    visemes = oculus_visemes(track)
    assert visemes.channels == OCULUS_VISEMES
    assert [visemes.channels[i] for i in visemes.values.argmax(axis=1)] == ["sil", "PP", "aa", "ih", "ou"]
    assert visemes["sil"][0] == 1.0 and np.all((visemes.values >= 0) & (visemes.values <= 1))
    write_track(track, tmp_path / "v.visemes.csv")
    lines = (tmp_path / "v.visemes.csv").read_text().splitlines()
    assert lines[0] == "time," + ",".join(OCULUS_VISEMES) and len(lines) == 6
    assert lines[2].startswith("0.040000,") and len(lines[2].split(",")) == 16
    write_track(track, tmp_path / "v.visemes.json")
    back = read_track(tmp_path / "v.visemes.json")
    assert back.channels == OCULUS_VISEMES and np.allclose(back.values, visemes.values, atol=5e-7)


def test_oculus_weights_sum_to_one_as_ovrlipsyncs_do():
    """A wide open rounded mouth hits several clipped controls at once (their sum passes 1), and a
    consonant's frames give its viseme the largest weight: every frame still sums to one."""
    table = poses("oculus_visemes")
    wide = {k: min(1.0, 1.5 * v) for k, v in {**table["viseme_aa"], **table["viseme_O"], **table["viseme_E"]}.items()}
    track = pose_track([{}, table["viseme_aa"], wide, wide, table["viseme_PP"]], fps=25)
    phones = PhoneSequence([Phone("sil", 0.0, 0.12), Phone("P", 0.12, 0.2)], "en")
    for visemes in (oculus_visemes(track), oculus_visemes(track, phones=phones)):
        assert np.allclose(visemes.values.sum(axis=1), 1.0, atol=1e-9)
        assert np.all((visemes.values >= 0) & (visemes.values <= 1))
    assert oculus_visemes(track)["sil"][0] == 1.0
    with_phones = oculus_visemes(track, phones=phones)
    assert with_phones["sil"][3:].max() == 0.0 and with_phones.values[3:].argmax(axis=1).tolist() == [1, 1]


def rhubarb_example() -> Track:
    shapes = poses("rhubarb_shapes")
    return pose_track([{}] * 3 + [shapes["A"]] * 2 + [shapes["D"]] * 4 + [{}], fps=10)


def test_mouth_cues_merge_runs():
    assert mouth_cues(rhubarb_example()) == [
        MouthCue(0.0, 0.3, "X"), MouthCue(0.3, 0.5, "A"), MouthCue(0.5, 0.9, "D"), MouthCue(0.9, 1.0, "X")]


def test_rhubarb_tsv_exactly(tmp_path):
    write_track(rhubarb_example(), tmp_path / "cues.tsv")
    assert (tmp_path / "cues.tsv").read_text() == "0.00\tX\n0.30\tA\n0.50\tD\n0.90\tX\n1.00\tX\n"


def test_rhubarb_json_exactly(tmp_path):
    write_track(rhubarb_example(), tmp_path / "cues.rhubarb.json", audio="hello.wav")
    assert (tmp_path / "cues.rhubarb.json").read_text() == (
        '{\n'
        '  "metadata": {\n'
        '    "soundFile": "hello.wav",\n'
        '    "duration": 1.00\n'
        '  },\n'
        '  "mouthCues": [\n'
        '    { "start": 0.00, "end": 0.30, "value": "X" },\n'
        '    { "start": 0.30, "end": 0.50, "value": "A" },\n'
        '    { "start": 0.50, "end": 0.90, "value": "D" },\n'
        '    { "start": 0.90, "end": 1.00, "value": "X" }\n'
        '  ]\n'
        '}\n'
    )
    with pytest.raises(VispeechError, match="rhubarb files cannot be read"):
        read_track(tmp_path / "cues.rhubarb.json")


def test_cues_at_high_frame_rates_round_to_centiseconds():
    shapes = poses("rhubarb_shapes")
    cues = mouth_cues(pose_track([{}] * 7 + [shapes["F"]] * 5, fps=120))
    assert cues == [MouthCue(0.0, 0.06, "X"), MouthCue(0.06, 0.1, "F")]


def test_mouth_cues_come_from_the_phones_when_they_are_known():
    """Rhubarb's rules on a said sentence: A on /p b m/, G on /f v/, H on /l/, D or C on open
    vowels, X in silence; every cue boundary on a phone boundary; no pose involved."""
    from vispeech.alignment.phones import n_frames_for
    from vispeech.pipeline import utter

    phones = utter("Bob will move five pale palms far away.", "en").phones
    track = Track(np.zeros((n_frames_for(phones.duration, 30), 1)), ("jawOpen",), 30)  # a pose: X throughout
    cues = mouth_cues(track, phones=phones)
    assert cues[0].start == 0 and cues[-1].end == round(track.n_frames / 30, 2)
    assert all(a.end == b.start and a.value != b.value for a, b in zip(cues, cues[1:]))
    expected = {"P": "A", "B": "A", "M": "A", "F": "G", "V": "G", "L": "H", "AA": "D", "AE": "C", "AY": "D",
                "EY": "C", "UW": "F", "W": "F", "sil": "X"}
    seen = set()
    for phone in phones:
        middle = (phone.start + phone.end) / 2
        cue = next(c for c in cues if c.start <= middle < c.end)
        if phone.symbol in expected:
            assert cue.value == expected[phone.symbol], (phone, cue)
            seen.add(phone.symbol)
    assert {"P", "B", "M", "F", "V", "L", "AA", "sil"} <= seen
    boundaries = {round(phone.start, 2) for phone in phones} | {round(phone.end, 2) for phone in phones}
    assert {c.start for c in cues} <= boundaries
    assert {c.value for c in mouth_cues(track, PoseTable.load("rhubarb_shapes"), phones)} == {"X"}  # the frames'


def test_format_dispatch():
    assert track_format("a.csv") == "livelink" and track_format("a.visemes.csv") == "oculus"
    assert track_format("A.JSON") == "json" and track_format("a.talkinghead.json") == "talkinghead"
    assert track_format("a.tsv") == "rhubarb" and track_format("a.rhubarb.json") == "rhubarb"
    assert track_format("a.glb") == "gltf" and track_format("a.FBX") == "fbx"
    assert set(FORMATS) == {"livelink", "json", "talkinghead", "oculus", "rhubarb", "gltf", "fbx"}
    with pytest.raises(VispeechError, match="known formats: livelink, json, talkinghead, oculus, rhubarb, gltf, fbx"):
        track_format("a.txt")
    with pytest.raises(VispeechError, match="unknown track format 'usd'"):
        write_track(small_track(), "a.json", "usd")
    with pytest.raises(VispeechError, match="cannot be read"):
        read_track("a.glb")


def test_csv_is_an_alias_of_livelink(tmp_path):
    from vispeech.pipeline import OUTPUT_FILES, check_formats

    assert track_format("a.txt", "csv") == "livelink" and "csv" not in FORMATS
    write_track(small_track(), tmp_path / "take.txt", "csv")
    assert np.allclose(read_track(tmp_path / "take.txt", "livelink")["jawOpen"], small_track()["jawOpen"])
    assert check_formats(["csv", "json"]) == ("livelink", "json")
    assert set(OUTPUT_FILES) - {"wav", "textgrid", "preview"} <= set(FORMATS)


def test_read_animation_keeps_what_json_holds(tmp_path):
    phones = PhoneSequence([Phone("sil", 0, 0.1), Phone("M", 0.1, 0.3, 0), Phone("sil", 0.3, 0.4)], "en",
                           [Word("mm", 0.1, 0.3)])
    write_track(small_track(), tmp_path / "a.json", phones=phones, audio="a.wav")
    write_track(small_track(), tmp_path / "a.csv", phones=phones, audio="a.wav")
    json_animation, csv_animation = read_animation(tmp_path / "a.json"), read_animation(tmp_path / "a.csv")
    assert json_animation.phones == phones and json_animation.audio == "a.wav"
    assert csv_animation.phones is None and csv_animation.audio is None
    assert np.allclose(csv_animation.track["jawOpen"], json_animation.track["jawOpen"])


def test_write_track_by_name_and_retargeting(tmp_path):
    track = small_track()
    write_track(track, tmp_path / "take.txt", "livelink")
    assert read_track(tmp_path / "take.txt", "livelink")["jawOpen"].tolist() == track["jawOpen"].tolist()
    write_track(track, tmp_path / "th.json", "talkinghead")
    assert read_track(tmp_path / "th.json").channels == track.channels
    from vispeech.motion.rigging.retarget import PoseTable
    write_track(track, tmp_path / "rig.json", pose_table=PoseTable.load("thesis_bone_rig"))
    rig = read_track(tmp_path / "rig.json")
    assert "jaw.rotation_x" in rig.channels
    assert np.allclose(rig["jaw.rotation_x"], np.round(0.35 * track["jawOpen"], 6))
    with pytest.raises(VispeechError, match="no Live Link Face channel"):
        write_track(rig, tmp_path / "rig.csv")
    write_track(track, tmp_path / "x.glb")  # onto the head the package ships
    assert (tmp_path / "x.glb").read_bytes()[:4] == b"glTF"


def test_every_reader_refuses_more_than_600_s_and_takes_600_s_at_any_rate(tmp_path):
    """The duration limit holds alike in every format: 700 frames at 1 fps are refused by the JSON
    and Live Link readers as by TalkingHead's, and 10 min at 29.97 fps (17982 frames, whose summed
    durations come to a hair over 600 s in floating point) reads back from each."""
    for n, fps, ok in ((700, 1.0, False), (17982, 29.97, True)):
        track = Track(np.full((n, 1), 0.1), ("jawOpen",), fps)
        for name in ("t.json", "t.csv", "t.talkinghead.json"):
            write_track(track, tmp_path / name)
            if ok:
                assert read_track(tmp_path / name).n_frames == n
            else:
                with pytest.raises(VispeechError, match="lasts 700 s; the limit is 600 s"):
                    read_track(tmp_path / name)


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_every_format_refuses_a_track_no_reader_would_take(fmt, tmp_path):
    """Checked once for all formats: glTF wrote NaN as a raw "Out of range float values are not JSON
    compliant", a track without frames was written where no reader takes it back, an fps of 0
    divided by zero; each is one line naming the file, and nothing is written."""
    good = Track(np.full((5, 2), 0.2), ("jawOpen", "mouthClose"), 30.0)
    nan = good.copy()
    nan.values[3, 1] = np.nan
    still = good.copy()
    still.fps = 0
    path = tmp_path / f"out{FORMATS[fmt].extensions[0]}"
    for track, message in ((nan, "frame 3, value 1 is nan"), (Track(np.zeros((0, 2)), good.channels, 30.0),
                           "the track has no frames"), (still, "fps must be positive")):
        with pytest.raises(VispeechError, match=f"^cannot write {path}: .*{message}"):
            write_track(track, path, fmt)
        assert not path.exists()


def test_tracks_and_phone_dicts_refuse_what_makes_no_sense_in_one_line():
    """Found by the API's QA: a NaN start time was taken (the viseme writers then raised "cannot
    convert float NaN to integer"), resample(inf) an OverflowError, resample(20, n_frames=-1) an empty
    track, from_dict ignored a wrong n_frames, and PhoneSequence.from_dict([1]) an AttributeError."""
    good = Track(np.zeros((2, 1)), ("jawOpen",), 30.0)
    for call, message in (
        (lambda: Track(np.zeros((2, 1)), ("jawOpen",), 30.0, float("nan")), "start time must be a number"),
        (lambda: good.resample(float("inf")), "fps must be positive, got inf"),
        (lambda: good.resample(20.0, n_frames=-1), "needs 1 frame or more, got n_frames=-1"),
        (lambda: Track.from_dict({**good.to_dict(), "n_frames": 5}), "n_frames is 5 but there are 2 frames"),
        (lambda: PhoneSequence.from_dict([1]), "malformed phone sequence"),
    ):
        with pytest.raises(VispeechError, match=message):
            call()
    assert Track.from_dict(good.to_dict()).n_frames == 2
