"""Live Link Face CSV: the iPhone's exact header, timecodes, and exact round trips."""

import numpy as np
import pytest

from vispeech import Track, VispeechError
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.motion.formats.livelink import (
    LIVELINK_CHANNELS,
    LIVELINK_COLUMNS,
    livelink_csv_texts,
    read_livelink_csv,
    write_livelink_csv,
)

IPHONE_HEADER = (
    "Timecode,BlendshapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,"
    "EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,MouthFunnel,MouthPucker,"
    "MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,"
    "MouthDimpleRight,MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,"
    "MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,"
    "MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,"
    "CheekSquintLeft,CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,"
    "LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)
EMOTIONS = "Angry,Disgusted,Fearful,Happy,Neutral,Sad,Surprised"


def random_track(n=75, fps=60.0, start_time=0.0, seed=0) -> Track:
    rng = np.random.default_rng(seed)
    values = np.round(rng.uniform(-0.3, 1.0, (n, len(LIVELINK_CHANNELS))), 10)
    return Track(values, LIVELINK_CHANNELS, fps, start_time)


def iphone_like_file(path, timecodes, seed=1):
    """A take in the app's layout: its header, then rows of 61 values with 10 decimals."""
    rng = np.random.default_rng(seed)
    rows = [IPHONE_HEADER]
    for tc in timecodes:
        rows.append(",".join([tc, "61"] + [f"{v:.10f}" for v in rng.uniform(-0.05, 0.6, 61)]))
    path.write_text("\n".join(rows) + "\n")


def test_header_is_exactly_the_iphones(tmp_path):
    write_livelink_csv(random_track(3), tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert lines[0] == IPHONE_HEADER
    fields = lines[0].split(",")
    assert len(fields) == 63 and fields.index("JawRight") < fields.index("JawLeft")
    assert fields.index("MouthRight") < fields.index("MouthLeft")
    assert set(LIVELINK_CHANNELS[:52]) == set(ARKIT_NAMES)
    assert LIVELINK_CHANNELS[52:55] == ("headYaw", "headPitch", "headRoll")
    row = lines[1].split(",")
    assert row[0] == "00:00:00:00.000" and row[1] == "61" and all(len(v.split(".")[1]) == 10 for v in row[2:])


def test_timecodes_count_frames_within_the_second(tmp_path):
    write_livelink_csv(random_track(62, fps=30.0), tmp_path / "t.csv")
    codes = [line.split(",")[0] for line in (tmp_path / "t.csv").read_text().splitlines()[1:]]
    assert codes[:2] == ["00:00:00:00.000", "00:00:00:01.000"]
    assert codes[29:32] == ["00:00:00:29.000", "00:00:01:00.000", "00:00:01:01.000"]
    assert codes[-1] == "00:00:02:01.000"


def test_start_timecode_and_subframe_fraction(tmp_path):
    track = random_track(3, fps=60.0, start_time=0.5 / 60)
    write_livelink_csv(track, tmp_path / "t.csv", start_timecode="01:02:03:04")
    codes = [line.split(",")[0] for line in (tmp_path / "t.csv").read_text().splitlines()[1:]]
    assert codes == ["01:02:03:04.500", "01:02:03:05.500", "01:02:03:06.500"]


@pytest.mark.parametrize("fps,start", [(60.0, 0.0), (30.0, 0.0), (25.0, 12.48), (30000 / 1001, 3600.0), (12.0, 0.0),
                                       (15.0, 0.0), (20.0, 0.0), (59.0, 0.0), (119.0, 0.5), (144.0, 0.5),
                                       (200.0, 0.75)])
def test_read_of_write_equals_track(tmp_path, fps, start):
    track = random_track(90, fps=fps, start_time=start)
    write_livelink_csv(track, tmp_path / "t.csv")
    back = read_livelink_csv(tmp_path / "t.csv")
    assert back.channels == LIVELINK_CHANNELS and back.fps == pytest.approx(fps, rel=1e-12)
    assert back.start_time == pytest.approx(start, abs=1e-9)
    assert np.max(np.abs(back.values - track.values)) <= 1e-10


def test_write_of_read_is_byte_exact_for_an_iphone_like_take(tmp_path):
    # A take starting at a non-zero timecode, crossing a second boundary, 60 rows per second.
    codes = [f"19:16:{29 + (35 + k) // 60:02d}:{(35 + k) % 60:02d}.273" for k in range(40)]
    iphone_like_file(tmp_path / "take.csv", codes)
    track = read_livelink_csv(tmp_path / "take.csv")
    assert track.fps == 60.0 and track.n_frames == 40
    assert track.start_time == pytest.approx(19 * 3600 + 16 * 60 + 29 + 35.273 / 60, abs=1e-9)
    write_livelink_csv(track, tmp_path / "again.csv")
    assert (tmp_path / "again.csv").read_bytes() == (tmp_path / "take.csv").read_bytes()


@pytest.mark.parametrize("fps,start,origin", [(30.0, 0.0, "00:00:00:00"), (120.0, 0.5, "99:59:59:00"),
                                              (29.97, 12.48, "12:00:00:00")])
def test_values_and_timecodes_are_printed_as_python_prints_them(tmp_path, fps, start, origin):
    """Every field as ``%02d`` and ``%.10f`` print it (the writer lays all rows out at once):
    ties of the 10th decimal, -0.0, tiny negatives, the widest values (±1e6), hours past 99."""
    rng = np.random.default_rng(int(fps))
    special = [0.0, -0.0, 1.0, 1 / 2048, -3 / 8192, 2.5e-10, 1.5e-10, -1e-11, 0.99999999995, 12.3456789012345,
               -999.5, 4.5e5 + 0.123, 999_999.99999999995, -1e6, 1e6, 5e-324]
    values = rng.random((130, len(LIVELINK_CHANNELS)))
    values[:, :len(special)] = special
    values[:, 20] = np.round(values[:, 20], 10) + 0.5e-10
    values[:, 21] = rng.uniform(-50, 50, 130)
    track = Track(values, LIVELINK_CHANNELS, fps, start)
    write_livelink_csv(track, tmp_path / "t.csv", start_timecode=origin)
    rate = int(np.ceil(fps))
    hours, minutes, seconds, frame = map(int, origin.split(":"))
    base = hours * 3600 + minutes * 60 + seconds + frame / rate
    expected = [IPHONE_HEADER]
    for k, row in enumerate(values.tolist()):
        frames, milli = divmod(round((base + start + k / fps) * rate * 1000), 1000)
        seconds, frame = divmod(frames, rate)
        code = f"{seconds // 3600:02d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}:{frame:02d}.{milli:03d}"
        expected.append(",".join([code, "61"] + [f"{v:.10f}" for v in row]))
    assert (tmp_path / "t.csv").read_text().split("\n") == expected + [""]


def test_real_iphone_timecodes_with_drift(tmp_path):
    # The first rows of an iPhone take (MySlate_164): the sub-frame fraction drifts.
    fractions = [273, 275, 276, 278, 278, 281, 282, 284, 285, 287, 288, 290, 291, 293, 295, 297, 298, 300,
                 301, 303, 304, 306, 308, 309, 311, 313, 314, 316, 317, 319, 321, 322, 324, 325, 327, 328, 330]
    codes = [f"19:16:{29 + (35 + k) // 60:02d}:{(35 + k) % 60:02d}.{f:03d}" for k, f in enumerate(fractions)]
    assert codes[24:26] == ["19:16:29:59.311", "19:16:30:00.313"]
    iphone_like_file(tmp_path / "take.csv", codes)
    track = read_livelink_csv(tmp_path / "take.csv")
    span = (36 + (330 - 273) / 1000) / 60
    assert track.fps == pytest.approx(36 / span) and 59.8 < track.fps < 60.0
    assert read_livelink_csv(tmp_path / "take.csv", fps=60).fps == 60.0


@pytest.mark.parametrize("rate,every", [(60, 5), (60, 6), (30, 3), (60, 2)])
def test_a_take_of_every_nth_frame_keeps_its_timecode_rate(tmp_path, rate, every):
    # rows every 5th frame of a 60 fps timecode end each second at 55: the rate is still 60, not 56
    codes = [f"10:00:{k * every // rate:02d}:{k * every % rate:02d}.000" for k in range(3 * rate // every)]
    iphone_like_file(tmp_path / "take.csv", codes)
    track = read_livelink_csv(tmp_path / "take.csv")
    assert track.fps == rate / every and track.start_time == 36000.0


def test_the_header_is_matched_in_any_case(tmp_path):
    # the app writes BlendshapeCount; PyLiveLinkFace-based scripts write BlendShapeCount
    rows = ["Timecode,BlendShapeCount,JawOpen"] + [f"00:00:00:{k:02d}.000,1,0.{k}" for k in range(3)]
    (tmp_path / "take.csv").write_text("\n".join(rows) + "\n")
    assert read_livelink_csv(tmp_path / "take.csv")["jawOpen"].tolist() == [0.0, 0.1, 0.2]


def test_neurosync_68_columns_are_tolerated(tmp_path):
    rows = [IPHONE_HEADER + "," + EMOTIONS]
    rows += [f"00:00:00:{k:02d}.000,68," + ",".join(["0.5000000000"] * 68) for k in range(3)]
    (tmp_path / "ns.csv").write_text("\n".join(rows) + "\n")
    track = read_livelink_csv(tmp_path / "ns.csv")
    assert track.channels[-7:] == ("angry", "disgusted", "fearful", "happy", "neutral", "sad", "surprised")
    assert track.fps == 60.0 and track["jawOpen"].tolist() == [0.5] * 3


def test_reordered_columns_and_missing_channels(tmp_path):
    rows = ["Timecode,BlendshapeCount,JawOpen,MouthClose"]
    rows += [f"00:00:{s:02d}:{f:02d}.000,2,0.{f:02d}00000000,0.1000000000" for s in (0, 1) for f in range(25)]
    (tmp_path / "few.csv").write_text("\n".join(rows) + "\n")
    track = read_livelink_csv(tmp_path / "few.csv")
    assert track.channels == ("jawOpen", "mouthClose") and track.fps == 25.0 and track.n_frames == 50
    write_livelink_csv(track, tmp_path / "full.csv")
    full = read_livelink_csv(tmp_path / "full.csv")
    assert np.array_equal(full["jawOpen"], track["jawOpen"]) and not full["tongueOut"].any()


@pytest.mark.parametrize("text,message", [
    ("", "empty"),
    ("Time,Count,JawOpen\n", "not a Live Link Face CSV"),
    ("Timecode,BlendshapeCount,JawOpen\n", "no frames"),
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1\n", "line 2: 2 fields"),
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00.000,1,0.1\n", "line 2: bad timecode"),
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,x\n", "line 2: a value is not a number"),
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00:01.000,1,0.1\n00:00:00:01.000,1,0.1\n",
     "line 3: timecode does not increase"),
])
def test_bad_files(tmp_path, text, message):
    (tmp_path / "bad.csv").write_text(text)
    with pytest.raises(VispeechError, match=message):
        read_livelink_csv(tmp_path / "bad.csv")


def test_bad_start_timecode_keeps_old_file(tmp_path):
    path = tmp_path / "t.csv"
    write_livelink_csv(random_track(2), path)
    before = path.read_bytes()
    with pytest.raises(VispeechError, match="start timecode"):
        write_livelink_csv(random_track(2, seed=3), path, start_timecode="soon")
    assert path.read_bytes() == before


def test_columns_constant_matches_header():
    assert ",".join(("Timecode", "BlendshapeCount") + LIVELINK_COLUMNS) == IPHONE_HEADER


def test_tracks_formatted_together_get_the_bytes_each_gets_alone(tmp_path):
    """Frames of several tracks in one pass (rates 24, 30 and 60, a take 35 hours in, degrees of
    head turn wider than the other values, signs in some tracks only, one and many frames): each
    file is the one write_livelink_csv writes; a track out of range is refused in its place."""
    tracks = [random_track(75, 60.0), random_track(1, 30.0, seed=1), random_track(40, 24.0, 2.5, seed=2),
              random_track(9, 30.0, 35 * 3600.0 + 0.5, seed=3), Track(np.full((4, 1), 0.25), ("jawOpen",), 30.0),
              random_track(33, 30.0, seed=4)]
    tracks[5].values[:] = np.abs(tracks[5].values)  # no minus sign in the whole file
    tracks[3].values[:, LIVELINK_CHANNELS.index("headYaw")] = [-123.25, 45.5, 0, 7, 180, -0.5, 99.999, 1, 2]
    wild = Track(np.full((3, 1), 1e300), ("jawOpen",), 30.0)
    texts = livelink_csv_texts([*tracks[:2], wild, *tracks[2:]])
    assert isinstance(texts[2], VispeechError) and "cannot write" in str(texts[2])
    del texts[2]
    for k, (track, text) in enumerate(zip(tracks, texts, strict=True)):
        write_livelink_csv(track, tmp_path / f"{k}.csv")
        assert text == (tmp_path / f"{k}.csv").read_bytes(), k
    assert livelink_csv_texts([]) == []
