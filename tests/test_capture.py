"""``vispeech capture``: takes from talking-face video with MediaPipe Face Landmarker (the capture
extra), checked against the GRID corpus's own tracks of the 10 videos in the shared folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import SHARED, require, require_module
from vispeech.cli import main
from vispeech.errors import VispeechError

GRID = SHARED / "data" / "grid_s1"
FACE_MODEL = SHARED / "models" / "face_landmarker.task"


@pytest.fixture(scope="module")
def videos() -> list[Path]:
    require_module("mediapipe", "MediaPipe (the capture extra)")
    require_module("av", "PyAV (the capture extra)")
    require(FACE_MODEL.is_file(), f"the face landmarker model ({FACE_MODEL})")
    require((GRID / "video").is_dir(), f"grid_s1's videos ({GRID / 'video'})")
    found = sorted((GRID / "video").glob("*.mpg"))
    assert len(found) == 10
    return found


@pytest.fixture(scope="module")
def face_model_env():
    before = os.environ.get("VISPEECH_FACE_MODEL")
    os.environ["VISPEECH_FACE_MODEL"] = str(FACE_MODEL)
    yield
    if before is None:
        del os.environ["VISPEECH_FACE_MODEL"]
    else:
        os.environ["VISPEECH_FACE_MODEL"] = before


@pytest.fixture(scope="module")
def captured(videos, tmp_path_factory) -> Path:
    """The 10 videos captured with their transcripts into one corpus folder (capture --batch), with
    the face model vispeech ships (no --face-model, no VISPEECH_FACE_MODEL)."""
    folder = tmp_path_factory.mktemp("videos")
    sentences = dict(line.split("\t") for line in (GRID / "sentences.tsv").read_text().splitlines())
    for video in videos:
        (folder / video.name).symlink_to(video)
        (folder / f"{video.stem}.txt").write_text(sentences[video.stem] + "\n")
    out = tmp_path_factory.mktemp("corpus")
    result = CliRunner().invoke(main, ["capture", str(folder), "--batch", "-o", str(out), "-j", "2"],
                                env={"VISPEECH_FACE_MODEL": None})
    assert result.exit_code == 0, result.output
    assert "10 captured, 0 already there, 0 failed" in result.output
    return out


def test_captured_tracks_are_the_corpus_tracks(captured, videos):
    """Same tracker, same video: the blend shapes, head pose and landmarks of every frame match the
    corpus's (jawOpen r ≥ 0.99 is the acceptance; they agree far closer)."""
    from vispeech.corpus.grid import read_face_csv

    for video in videos:
        got, got_landmarks, got_mask = read_face_csv(captured / f"{video.stem}.face.csv")
        want, want_landmarks, want_mask = read_face_csv(GRID / "utterances" / f"{video.stem}.csv")
        assert got.n_frames == want.n_frames and got.fps == want.fps == 25.0
        assert got.channels == want.channels  # the corpus's columns, in its order
        assert np.array_equal(got_mask, want_mask)
        both = got_mask & want_mask
        r = np.corrcoef(got["jawOpen"][both], want["jawOpen"][both])[0, 1]
        assert r >= 0.999, (video.stem, r)
        blend = [c for c in got.channels if not c.startswith("head")]
        assert np.abs(got.select(blend).values - want.select(blend).values)[both].max() < 0.02, video.stem
        head = got.select(["headYaw", "headPitch", "headRoll"]).values - want.select(["headYaw", "headPitch", "headRoll"]).values
        assert np.abs(head[both]).max() < 0.5, video.stem  # degrees
        for name, points in want_landmarks.items():
            assert np.abs(got_landmarks[name] - points)[both].max() < 2e-3, (video.stem, name)


def test_a_captured_corpus_trains_a_model_that_loads_and_predicts(captured, tmp_path):
    require_module("torch", "torch (the train extra)")
    from test_contract import TINY_NETWORKS

    from vispeech.corpus.takes import read_takes
    from vispeech.models.registry import create_model, load_model

    corpus = read_takes(captured, language="en", strict=True)
    utterances = list(corpus)
    assert len(utterances) == 10 and all(u.phones is not None and u.landmarks for u in utterances)
    assert {"lm13", "lm14", "lm33", "lm263"} <= set(utterances[0].landmarks)
    sentences = dict(line.split("\t") for line in (GRID / "sentences.tsv").read_text().splitlines())
    for utterance in utterances:
        assert [w.text for w in utterance.words] == sentences[utterance.id].split()
    model = create_model("tdnn-beskow", **TINY_NETWORKS["tdnn-beskow"], targets=["jawOpen", "mouthClose"],
                         epochs=2).fit(utterances, progress=False, num_threads=1)
    model.save(tmp_path / "model")
    again = load_model(tmp_path / "model")
    track = again.predict(utterances[0].phones, 25.0)
    assert track.n_frames == utterances[0].track.n_frames and track.channels == ("jawOpen", "mouthClose")
    np.testing.assert_allclose(track.values, model.predict(utterances[0].phones, 25.0).values)


def test_a_rerun_skips_complete_takes(captured, videos, tmp_path):
    folder = tmp_path / "again"
    folder.mkdir()
    (folder / videos[0].name).symlink_to(videos[0])
    (folder / videos[1].name).symlink_to(videos[1])
    result = CliRunner().invoke(main, ["capture", str(folder), "--batch", "-o", str(captured)])
    assert result.exit_code == 0 and "0 captured, 2 already there, 0 failed" in result.output, result.output
    # a take is complete with its .face.csv and its CSV (moved in last); a CSV alone is no capture's
    # (a Live Link recording, or a take an older version left half-moved) and is not replaced either
    import shutil

    corpus = shutil.copytree(captured, tmp_path / "corpus")
    (corpus / f"{videos[0].stem}.face.csv").unlink()
    result = CliRunner().invoke(main, ["capture", str(folder), "--batch", "-o", str(corpus)])
    assert result.exit_code == 1 and "0 captured, 1 already there, 1 failed" in result.output, result.output
    assert f"failed {videos[0].stem}: {corpus / videos[0].stem}.csv is no take vispeech captured" in result.output


def _write_video(path: Path, frames: list[np.ndarray], fps: int = 25, audio: np.ndarray | None = None,
                 rate: int = 16000, codec: str = "aac") -> None:
    """A video (MPEG-4) of RGB ``frames``, with ``audio`` in ``codec`` when given (``pcm_s16le``, with
    no encoder delay, in a Matroska file)."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=fps)
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt, stream.bit_rate = "yuv420p", 4_000_000
        sound = container.add_stream(codec, rate=rate, layout="mono") if audio is not None else None
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        container.mux(stream.encode())
        if sound is not None:
            pcm = (np.clip(audio, -1, 1) * 32767).astype(np.int16)
            for start in range(0, len(pcm), 1024):
                chunk = av.AudioFrame.from_ndarray(pcm[None, start:start + 1024], format="s16", layout="mono")
                chunk.sample_rate = rate
                container.mux(sound.encode(chunk))
            container.mux(sound.encode())


def _grid_frames(video: Path) -> list[np.ndarray]:
    import av

    with av.open(str(video)) as container:
        return [np.ascontiguousarray(f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]


def test_frames_where_the_face_leaves_are_marked_not_invented(videos, face_model_env, tmp_path):
    from vispeech.corpus.capture import capture_take
    from vispeech.corpus.takes import read_takes
    from vispeech.frontends.audio import read_audio

    frames = _grid_frames(videos[0])
    gone = range(30, 45)
    for k in gone:
        frames[k] = np.zeros_like(frames[k])  # the face is out of the picture
    audio, rate = read_audio(GRID / "utterances" / f"{videos[0].stem}.flac")
    video = tmp_path / "walks_off.mp4"
    _write_video(video, frames, audio=audio, rate=rate)
    report = capture_take(video, tmp_path / "take", text="bin blue at f two now")
    assert report.frames == 75 and report.missing == len(gone)
    rows = (tmp_path / "take" / "walks_off.face.csv").read_text().splitlines()[1:]
    assert all(rows[k].rstrip(",").count(",") == 1 for k in gone)  # frame and time only
    assert all(rows[k].count(",") > 100 and ",," not in rows[k] for k in range(75) if k not in gone)
    (utterance,) = list(read_takes(tmp_path / "take", language="en", strict=True))
    assert np.flatnonzero(~utterance.frame_mask).tolist() == list(gone)


@pytest.mark.parametrize("kind", ["no face", "no audio", "unreadable", "no face model"])
def test_bad_videos_are_one_line_errors(kind, videos, face_model_env, tmp_path):
    video = tmp_path / "bad.mp4"
    noise = np.random.default_rng(0).uniform(-0.1, 0.1, 16000)
    grey = [np.full((288, 360, 3), 128, np.uint8) for _ in range(25)]
    if kind == "no face":
        _write_video(video, grey, audio=noise)
    elif kind == "no audio":
        _write_video(video, _grid_frames(videos[0])[:25])
    elif kind == "unreadable":
        video.write_bytes(b"\x00\x01 not a video" * 50)
    else:
        _write_video(video, grey, audio=noise)
    env = {"VISPEECH_FACE_MODEL": str(tmp_path / "missing.task")} if kind == "no face model" else {}
    result = CliRunner().invoke(main, ["capture", str(video), "-o", str(tmp_path / "take")], env=env)
    expected = {"no face": "no face found in any of its 25 frames", "no audio": "has no audio track",
                "unreadable": "not a video file vispeech can read", "no face model": "face model not found"}[kind]
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and expected in errors[0], result.output
    assert not (tmp_path / "take").exists()


def test_everything_but_capture_works_without_mediapipe(tmp_path):
    """With mediapipe and PyAV unimportable, capture says which extra to install and the rest of
    the package (say, the take reader, the server's modules) imports and runs."""
    script = f"""
import sys
sys.modules["mediapipe"] = None
sys.modules["av"] = None
from click.testing import CliRunner
from vispeech.cli import main
result = CliRunner().invoke(main, ["capture", "x.mp4", "-o", r"{tmp_path / 'take'}"])
print(result.exit_code, [line for line in result.output.splitlines() if line.startswith("error:")])
import vispeech.corpus.capture, vispeech.corpus.takes, vispeech.pipeline, vispeech.streaming
said = CliRunner().invoke(main, ["say", "Hello.", "-o", r"{tmp_path / 'said'}"])
print(said.exit_code)
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    lines = out.stdout.strip().splitlines()
    assert lines[0].startswith("2 ['error: vispeech capture needs") and 'pip install "vispeech[capture]"' in lines[0], out
    assert lines[-1] == "0", out.stderr[-2000:]
    assert (tmp_path / "said" / "animation.csv").is_file()


def test_the_shipped_face_model_unless_another_is_named(monkeypatch, tmp_path):
    """MediaPipe's model ships as Google publishes it (the sha256 of shared/models/README.md), with its
    licence; --face-model, then VISPEECH_FACE_MODEL, name another; nothing is downloaded."""
    import hashlib

    from vispeech.frontends.video import SHIPPED_FACE_MODEL, face_model_path

    monkeypatch.delenv("VISPEECH_FACE_MODEL", raising=False)
    assert face_model_path() == SHIPPED_FACE_MODEL
    assert hashlib.sha256(SHIPPED_FACE_MODEL.read_bytes()).hexdigest() == \
        "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"
    assert (SHIPPED_FACE_MODEL.parent / "LICENSE-MediaPipe.txt").read_text().split()[:3] == ["Apache", "License", "Version"]
    named, other = tmp_path / "named.task", tmp_path / "other.task"
    named.write_bytes(b"a")
    other.write_bytes(b"b")
    monkeypatch.setenv("VISPEECH_FACE_MODEL", str(other))
    assert face_model_path() == other and face_model_path(named) == named
    monkeypatch.setenv("VISPEECH_FACE_MODEL", str(tmp_path / "missing.task"))
    with pytest.raises(VispeechError, match="face model not found"):
        face_model_path()


def _joined_corpus_takes(start: int, count: int = 10):
    """``count`` grid_s1 utterances from ``start`` joined into one take: lip gap per frame (NaN
    where untracked), sound fitted to the frames, as the corpus holds them."""
    from vispeech.corpus.articulation import lip_gap
    from vispeech.corpus.grid import read_face_csv
    from vispeech.frontends.audio import read_audio

    require(GRID.is_dir(), f"grid_s1 ({GRID})")
    ids = sorted(p.stem for p in (GRID / "utterances").glob("*.csv"))[start:start + count]
    gaps, sounds = [], []
    for name in ids:
        _, landmarks, mask = read_face_csv(GRID / "utterances" / f"{name}.csv")
        samples, rate = read_audio(GRID / "utterances" / f"{name}.flac")
        gap = lip_gap(landmarks, (360, 288))
        gaps.append(np.where(mask, gap, np.nan))
        n = round(len(gap) / 25 * rate)
        sounds.append(np.concatenate([samples, np.zeros(max(0, n - len(samples)))])[:n])
    return np.concatenate(gaps), np.concatenate(sounds), rate


@pytest.mark.parametrize("late", [0.0, 0.2, -0.15])
def test_the_offset_of_sound_and_picture_is_measured(late):
    """30 s of grid_s1 (in sync, utterances 300-319: not those NATURAL_LAG was measured on), and
    the same with the sound moved: the estimate finds the picture ``late`` within 45 ms."""
    from vispeech.corpus.av_sync import estimate_offset

    for start in (300, 310):
        gap, sound, rate = _joined_corpus_takes(start)
        shift = round(late * rate)  # picture late = sound early: drop the sound's start
        moved = np.concatenate([sound[shift:], np.zeros(shift)]) if shift >= 0 else np.concatenate(
            [np.zeros(-shift), sound[:shift]])
        offset = estimate_offset(gap, 25.0, moved, rate)
        assert abs(offset - late) < 0.045, (start, late, offset)
    assert np.isnan(estimate_offset(gap[:200], 25.0, sound[:200 * rate // 25], rate))  # 8 s: too short to tell


def test_sync_puts_a_late_picture_back_in_time(videos, face_model_env, tmp_path):
    """Four grid_s1 videos joined (12 s) with the picture 200 ms late: capture measures it, and
    with sync the face track lines up with the corpus's own track of the same frames again."""
    from vispeech.corpus.capture import capture_take
    from vispeech.corpus.grid import read_face_csv
    from vispeech.frontends.audio import read_audio

    frames, sounds, wanted = [], [], []
    for video in videos[:4]:
        frames += _grid_frames(video)
        samples, rate = read_audio(GRID / "utterances" / f"{video.stem}.flac")
        n = round(75 / 25 * rate)
        sounds.append(np.concatenate([samples, np.zeros(max(0, n - len(samples)))])[:n])
        wanted.append(read_face_csv(GRID / "utterances" / f"{video.stem}.csv")[0]["jawOpen"])
    late = [frames[0]] * 5 + frames[:-5]  # every picture 5 frames (200 ms) after its sound
    video = tmp_path / "late.mkv"
    _write_video(video, late, audio=np.concatenate(sounds), rate=rate, codec="pcm_s16le")
    plain = capture_take(video, tmp_path / "plain")
    synced = capture_take(video, tmp_path / "synced", sync=True, smooth=True)
    assert abs(plain.offset - 0.2) < 0.045 and not plain.synced and synced.synced, plain
    want = np.concatenate(wanted)
    for folder, best in ((tmp_path / "plain", 5), (tmp_path / "synced", 0)):
        got = read_face_csv(folder / f"late.face.csv")[0]["jawOpen"]
        r = [np.corrcoef(got[lag:lag + 250], want[:250])[0, 1] for lag in range(8)]
        assert int(np.argmax(r)) == best, (folder.name, np.round(r, 3))


GRID_TEST_IDS = ["bbaf2n", "bbas3a", "bbbm2p", "bbbmzn", "bgan4n"]  # grid_s1's test split: no model trained on them


@pytest.mark.parametrize("late", [0.12, -0.08])
def test_a_speech_model_tells_the_offset_of_a_3_s_take(late):
    """On five 3-s grid_s1 takes of the test split with the picture moved by ``late``, the jaw
    opening the live audio model hears in the sound finds it within 40 ms, where the sound's
    energy needs 10 s; under 3 s it tells nothing."""
    from vispeech.corpus.articulation import lip_gap
    from vispeech.corpus.av_sync import ANALYSIS_RATE, estimate_offset, openness_offset, shift_frames
    from vispeech.corpus.grid import read_face_csv
    from vispeech.frontends.audio import AudioClip, read_audio
    from vispeech.models.registry import load_model

    require(GRID.is_dir(), f"grid_s1 ({GRID})")
    model = load_model("grid-audio-cnn")
    for name in GRID_TEST_IDS:
        _, landmarks, mask = read_face_csv(GRID / "utterances" / f"{name}.csv")
        samples, rate = read_audio(GRID / "utterances" / f"{name}.flac")
        gap = shift_frames(np.where(mask, lip_gap(landmarks, (360, 288)), np.nan)[:, None], -late, 25.0)[:, 0]
        openness = model.predict(AudioClip.from_array(samples, rate), ANALYSIS_RATE).select(["jawOpen"]).values[:, 0]
        assert abs(openness_offset(gap, 25.0, openness) - late) < 0.04, name
        assert np.isnan(estimate_offset(gap, 25.0, samples, rate))
    assert np.isnan(openness_offset(gap[:70], 25.0, openness))  # 2.8 s


def test_sync_puts_a_3_s_take_back_in_time_from_what_the_sound_says(videos, face_model_env, tmp_path):
    """One grid_s1 video (3 s, test split) with the picture 120 ms late: with vispeech's speech
    openness (what `vispeech capture` passes) the offset is told and synced; without it, as
    before, a 3-s take's offset cannot be told and --sync is a one-line error."""
    from functools import partial

    from vispeech.corpus.capture import capture_take
    from vispeech.frontends.audio import read_audio
    from vispeech.pipeline import speech_openness

    frames = _grid_frames(videos[0])
    samples, rate = read_audio(GRID / "utterances" / f"{videos[0].stem}.flac")
    n = round(len(frames) / 25 * rate)
    video = tmp_path / "late.mkv"
    _write_video(video, [frames[0]] * 3 + frames[:-3], audio=np.concatenate([samples, np.zeros(n)])[:n], rate=rate,
                 codec="pcm_s16le")
    synced = capture_take(video, tmp_path / "synced", sync=True, openness=partial(speech_openness, language="en"))
    assert abs(synced.offset - 0.12) < 0.045 and synced.synced, synced
    plain = capture_take(video, tmp_path / "plain")
    assert np.isnan(plain.offset) and not plain.synced
    with pytest.raises(VispeechError, match=r"cannot tell the sound.s offset from the picture \(it needs 10 s of speech\)"):
        capture_take(video, tmp_path / "refused", sync=True)
    result = CliRunner().invoke(main, ["capture", str(video), "-o", str(tmp_path / "cli"), "--sync"])
    assert result.exit_code == 0, result.output
    said = next(line for line in result.output.splitlines() if line.startswith("audio-video offset"))
    assert said.endswith("ms late (moved back in time with the sound)") and abs(int(said.split()[5]) - 120) < 45, said


def test_smoothing_takes_jitter_and_keeps_speech():
    """On 20 grid_s1 tracks the Savitzky–Golay filter cuts jawOpen's frame-to-frame jitter (mean
    absolute second difference) by a quarter or more and keeps its movements (r > 0.98); frames
    without a face stay empty."""
    from vispeech.corpus.av_sync import smooth_frames
    from vispeech.corpus.grid import read_face_csv

    require(GRID.is_dir(), f"grid_s1 ({GRID})")
    ratios = []
    for path in sorted((GRID / "utterances").glob("*.csv"))[:20]:
        track = read_face_csv(path)[0]
        raw = track["jawOpen"]
        smoothed = smooth_frames(track.values, 25.0)[:, track.channels.index("jawOpen")]
        ratios.append(np.abs(np.diff(smoothed, 2)).mean() / np.abs(np.diff(raw, 2)).mean())
        assert np.corrcoef(smoothed, raw)[0, 1] > 0.98, path.stem
    assert np.median(ratios) < 0.75, ratios
    values = track.values.copy()
    values[40:43] = np.nan
    smoothed = smooth_frames(values, 25.0)
    assert np.isnan(smoothed[40:43]).all() and np.isfinite(np.delete(smoothed, range(40, 43), axis=0)).all()


def test_an_iphone_recording_is_imported_with_its_timecodes_lined_up(videos, tmp_path):
    """A Live Link Face recording: the app's CSV (a grid_s1 track, its first row at timecode
    10:00:00:10) and its .mov (timecode 10:00:00:00, with the sound). The take starts with the
    sound: the CSV's rows land 10 frames in, the 10 frames before them are marked empty."""
    import av

    from vispeech.corpus.grid import read_face_csv
    from vispeech.corpus.takes import read_takes
    from vispeech.frontends.audio import read_audio
    from vispeech.motion.formats.livelink import write_livelink_csv

    recorded = read_face_csv(GRID / "utterances" / f"{videos[0].stem}.csv")[0]
    csv = tmp_path / "take01_iPhone.csv"
    write_livelink_csv(recorded, csv, start_timecode="10:00:00:10")
    samples, rate = read_audio(GRID / "utterances" / f"{videos[0].stem}.flac")
    mov = tmp_path / "take01_iPhone.mov"
    with av.open(str(mov), "w", format="mov") as container:
        picture = container.add_stream("mpeg4", rate=25)
        picture.width, picture.height, picture.pix_fmt = 64, 48, "yuv420p"
        picture.metadata["timecode"] = "10:00:00:00"
        sound = container.add_stream("pcm_s16le", rate=rate, layout="mono")
        for _ in range(75):
            container.mux(picture.encode(av.VideoFrame.from_ndarray(np.zeros((48, 64, 3), np.uint8), format="rgb24")))
        container.mux(picture.encode())
        frame = av.AudioFrame.from_ndarray((samples * 32767).astype(np.int16)[None], format="s16", layout="mono")
        frame.sample_rate = rate
        container.mux(sound.encode(frame))
        container.mux(sound.encode())
    out = tmp_path / "take"
    result = CliRunner().invoke(main, ["capture", str(mov), "--livelink", str(csv), "--text", "bin blue at f two now",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "first row at +0.400 s of the sound" in result.output and "10 not covered" in result.output
    (take,) = list(read_takes(out, language="en", strict=True))
    assert take.track.n_frames == 75 and np.flatnonzero(~take.frame_mask).tolist() == list(range(10))
    np.testing.assert_allclose(take.track["jawOpen"][10:], recorded["jawOpen"][:65], atol=1e-4)
    assert [w.text for w in take.words] == ["bin", "blue", "at", "f", "two", "now"]
    livelink = (out / "take01_iPhone.csv").read_text().splitlines()
    assert len(livelink) == 76 and livelink[1].startswith("00:00:00:00")
    # the walkthrough imports each iPhone take into the corpus folder: a second one goes in beside
    # the first (it was refused: "holds files vispeech did not write"), and a take imported again
    # replaces its own files only (here without a transcript: its old phones go)
    import shutil

    shutil.copy(mov, tmp_path / "take02_iPhone.mov")
    shutil.copy(csv, tmp_path / "take02_iPhone.csv")
    result = CliRunner().invoke(main, ["capture", str(tmp_path / "take02_iPhone.mov"), "--livelink",
                                       str(tmp_path / "take02_iPhone.csv"), "--text", "bin blue at f two now",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(t.id for t in read_takes(out, language="en", strict=True)) == ["take01_iPhone", "take02_iPhone"]
    result = CliRunner().invoke(main, ["capture", str(mov), "--livelink", str(csv), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert not (out / "take01_iPhone.TextGrid").exists() and (out / "take02_iPhone.TextGrid").is_file()
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"take0{k}_iPhone{suffix}" for k in (1, 2) for suffix in (".wav", ".face.csv", ".csv")]
        + ["take02_iPhone.TextGrid"]
    )
    # the app names its CSV as the video: a corpus folder holding the recording would lose it
    before = csv.read_bytes()
    result = CliRunner().invoke(main, ["capture", str(mov), "--livelink", str(csv), "-o", str(tmp_path)])
    assert result.exit_code == 2 and "take01_iPhone.csv is no take vispeech captured" in result.output, result.output
    assert csv.read_bytes() == before
    # so would a capture of the video by MediaPipe (no --livelink) into that folder
    result = CliRunner().invoke(main, ["capture", str(mov), "-o", str(tmp_path)])
    assert result.exit_code == 2 and "is no take vispeech captured" in result.output, result.output
    assert csv.read_bytes() == before
    # stopped halfway through moving a take in (here: killed before its Live Link CSV, moved last),
    # the take is left out with a warning, never read as files of two captures
    import vispeech.corpus.capture as capture_module

    moved = []

    def replace_then_die(source, target):
        if str(target).endswith("take01_iPhone.csv"):
            raise KeyboardInterrupt
        moved.append(Path(target).name)
        os.replace(source, target)

    capture_module_os = capture_module.os
    try:
        capture_module.os = SimpleNamespace(**{**vars(os), "replace": replace_then_die})
        with pytest.raises(KeyboardInterrupt):
            capture_module.import_livelink_take(csv, mov, out, text="bin blue at f two now")
    finally:
        capture_module.os = capture_module_os
    assert "take01_iPhone.TextGrid" in moved and not (out / "take01_iPhone.csv").exists()
    with pytest.warns(UserWarning, match="skipped take take01_iPhone: missing take01_iPhone.csv"):
        assert [t.id for t in read_takes(out, language="en")] == ["take02_iPhone"]
