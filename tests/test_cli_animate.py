"""``vispeech animate AUDIO``: its outputs, its two paths (audio model; transcript, alignment and
phone model) and its answers to bad input."""

import shutil
import struct
import time
import wave
import zlib
from pathlib import Path

import numpy as np
import pytest
import soundfile

from conftest import SHARED, require, require_module
from test_cli_say import SAY_FILES, assert_clean_error, run
from vispeech.alignment.formats import read_alignment
from vispeech.frontends.audio import AudioClip
from vispeech.limits import MAX_DURATION_S
from vispeech.motion.formats.livelink import read_livelink_csv
from vispeech.motion.formats.registry import read_track

ANIMATE_FILES = SAY_FILES - {"phones.TextGrid"}
"""What ``animate`` writes without ``--text``."""
GRID_ID = "bbaf2n"
"""A GRID utterance of the test split (no tiny model below trains on it)."""
GRID_TEXT = "bin blue at f two now"
SWEDISH = "Mamma plockar blåbär."


@pytest.fixture(scope="module")
def grid() -> Path:
    """GRID speaker 1, as the ``grid_s1`` fixture gives it, for module-scoped fixtures."""
    folder = SHARED / "data" / "grid_s1"
    require(folder.is_dir(), f"GRID speaker 1 ({folder})")
    return folder


@pytest.fixture(scope="module")
def audio_model(grid, tmp_path_factory) -> Path:
    """The folder of a tiny ``audio-cnn`` trained for one epoch on 8 GRID utterances (2 to validate)."""
    require_module("torch", "torch (the train extra)")
    from vispeech.corpus import align_corpus, read_grid, split_of
    from vispeech.models.fitting import Splits
    from vispeech.models.registry import create_model

    texts = dict(line.split("\t") for line in (grid / "sentences.tsv").read_text().splitlines()[1:])
    ids = [i for i in texts if split_of(i) == "train"][:8] + [i for i in texts if split_of(i) == "validation"][:2]
    root = tmp_path_factory.mktemp("grid")
    (root / "utterances").mkdir()
    for uid in ids:
        for ext in ("flac", "align", "csv"):
            shutil.copy(grid / "utterances" / f"{uid}.{ext}", root / "utterances")
    (root / "sentences.tsv").write_text("id\ttext\n" + "".join(f"{uid}\t{texts[uid]}\n" for uid in ids))
    corpus = align_corpus(read_grid(root, cache=tmp_path_factory.mktemp("cache")), progress=False)
    model = create_model("audio-cnn", epochs=1, channels=[16, 16, 16], pitch_copies=0)
    model.fit(Splits(corpus.split("train"), corpus.split("validation")), progress=False)
    return model.save(tmp_path_factory.mktemp("models") / "audio-cnn")


@pytest.fixture
def grid_clip(grid_s1) -> Path:
    return grid_s1 / "utterances" / f"{GRID_ID}.flac"


def grid_samples(grid_s1: Path) -> np.ndarray:
    """The GRID clip's samples (float32, 16 kHz)."""
    samples, _ = soundfile.read(grid_s1 / "utterances" / f"{GRID_ID}.flac", dtype="float32")
    return samples


def speech_frames(grid_s1: Path, n_frames: int, fps: float = 30.0) -> np.ndarray:
    """Which frames lie inside a word of the GRID clip (its own word timings, 1/25000 s units)."""
    times = np.arange(n_frames) / fps
    inside = np.zeros(n_frames, bool)
    for line in (grid_s1 / "utterances" / f"{GRID_ID}.align").read_text().split("\n"):
        if line.strip():
            start, end, word = line.split()
            if word not in ("sil", "sp"):
                inside |= (times >= int(start) / 25000) & (times < int(end) / 25000)
    return inside


def animate(audio: Path, out: Path, *args: str):
    """Run ``vispeech animate AUDIO -o OUT ARGS`` and check it succeeded."""
    result = run("animate", str(audio), "-o", str(out), *args)
    assert result.exit_code == 0, result.output
    return result


def check_outputs(out: Path, duration: float, sample_rate: int, fps: float = 30.0, textgrid: bool = False):
    """The folder's files agree with audio of ``duration`` s; returns the animation track."""
    assert {p.name for p in out.iterdir()} == (SAY_FILES if textgrid else ANIMATE_FILES)
    with wave.open(str(out / "speech.wav")) as wav:
        assert wav.getnchannels() == 1 and wav.getsampwidth() == 2 and wav.getframerate() == sample_rate
        assert wav.getnframes() / sample_rate == pytest.approx(duration, abs=1 / fps)
    track = read_track(out / "animation.json")
    assert track.fps == fps and abs(track.n_frames - duration * fps) <= 1
    rows = (out / "animation.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert header[:2] == ["Timecode", "BlendshapeCount"] and len(header) == 2 + 61  # Live Link Face
    assert rows[1].startswith("00:00:00:00") and len(rows) - 1 == track.n_frames
    assert read_livelink_csv(out / "animation.csv").n_frames == track.n_frames
    values = track.values
    assert np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= 1.0
    assert "<audio" in (out / "preview.html").read_text()
    return track


def write_audio(path: Path, samples: np.ndarray, sample_rate: int, **kwargs) -> Path:
    soundfile.write(path, samples, sample_rate, **kwargs)
    return path


# ---- the audio model: outputs, formats, rates, channels -------------------------------------


def test_audio_model_writes_every_file_but_the_textgrid(audio_model, grid_clip, tmp_path):
    out = tmp_path / "out"
    result = animate(grid_clip, out, "--model", str(audio_model))
    duration = soundfile.info(grid_clip).duration
    check_outputs(out, duration, 16000)
    lines = result.stdout.splitlines()
    assert lines[0] == f"90 frames at 30 fps, {duration:.2f} s -> {out}/"
    assert sorted(line.strip() for line in lines[1:]) == sorted(ANIMATE_FILES)
    written, _ = soundfile.read(out / "speech.wav", dtype="float32")  # the clip itself, as 16-bit PCM
    np.testing.assert_allclose(written, soundfile.read(grid_clip, dtype="float32")[0], atol=2 / 32768)


def test_audio_model_opens_the_mouth_on_speech(audio_model, grid_s1, grid_clip, tmp_path):
    animate(grid_clip, tmp_path / "speech", "--model", str(audio_model))
    jaw = read_track(tmp_path / "speech" / "animation.json")["jawOpen"]
    inside = speech_frames(grid_s1, len(jaw))
    assert jaw[inside].mean() > 1.5 * jaw[~inside].mean()
    silence = write_audio(tmp_path / "silence.wav", np.zeros(3 * 16000, np.float32), 16000)
    animate(silence, tmp_path / "silence", "--model", str(audio_model))
    closed = read_track(tmp_path / "silence" / "animation.json")["jawOpen"]
    assert np.median(closed) < 0.05 and closed.mean() < 0.5 * jaw[inside].mean()


def test_default_audio_model(grid_s1, grid_clip, tmp_path):
    """Without --model the shipped audio model (grid-audio-cnn) animates the audio."""
    out = tmp_path / "out"
    animate(grid_clip, out)
    jaw = check_outputs(out, soundfile.info(grid_clip).duration, 16000)["jawOpen"]
    inside = speech_frames(grid_s1, len(jaw))
    assert jaw[inside].mean() > 1.5 * jaw[~inside].mean()


@pytest.mark.parametrize("fmt,subtype", [("WAV", "PCM_16"), ("FLAC", "PCM_16"), ("MP3", "MPEG_LAYER_III"),
                                         ("OGG", "VORBIS")])
def test_audio_formats(audio_model, grid_s1, tmp_path, fmt, subtype):
    require(fmt in soundfile.available_formats() and subtype in soundfile.available_subtypes(fmt),
            f"libsndfile with {fmt}/{subtype}")
    path = write_audio(tmp_path / f"in.{fmt.lower()}", grid_samples(grid_s1), 16000, format=fmt, subtype=subtype)
    animate(path, tmp_path / "out", "--model", str(audio_model))
    check_outputs(tmp_path / "out", soundfile.info(path).duration, 16000)


@pytest.mark.parametrize("rate,kept", [(8000, 8000), (48000, 48000), (96000, 48000)])
def test_sample_rates(audio_model, grid_s1, tmp_path, rate, kept):
    """Any rate is animated; speech.wav keeps it up to 48 kHz and is resampled to 48 kHz above."""
    samples = AudioClip.from_array(grid_samples(grid_s1), 16000).resampled(rate).samples
    path = write_audio(tmp_path / "in.wav", samples, rate)
    animate(path, tmp_path / "out", "--model", str(audio_model), "--fps", "25")
    check_outputs(tmp_path / "out", len(samples) / rate, kept, fps=25.0)


def test_stereo_is_downmixed(audio_model, grid_s1, tmp_path):
    mono = grid_samples(grid_s1)
    path = write_audio(tmp_path / "stereo.wav", np.column_stack([mono, 0.5 * mono]), 16000, subtype="FLOAT")
    animate(path, tmp_path / "out", "--model", str(audio_model))
    check_outputs(tmp_path / "out", len(mono) / 16000, 16000)
    written, _ = soundfile.read(tmp_path / "out" / "speech.wav", dtype="float32")
    np.testing.assert_allclose(written, 0.75 * mono, atol=2 / 32768)


def test_no_postprocess_and_fps(audio_model, grid_clip, tmp_path):
    animate(grid_clip, tmp_path / "out", "--model", str(audio_model), "--postprocessing", "none", "--fps", "60")
    check_outputs(tmp_path / "out", soundfile.info(grid_clip).duration, 16000, fps=60.0)


# ---- a transcript: alignment and a phone model (or an audio model) --------------------------


def test_transcript_in_english(grid_clip, tmp_path):
    """--text aligns the transcript; the default phone model (grid-tdnn) animates its phones."""
    out = tmp_path / "out"
    animate(grid_clip, out, "--text", "Bin blue at F two now.")
    duration = soundfile.info(grid_clip).duration
    check_outputs(out, duration, 16000, textgrid=True)
    phones = read_alignment(out / "phones.TextGrid")
    assert [w.text for w in phones.words] == GRID_TEXT.split()
    assert phones.duration == pytest.approx(duration, abs=0.01)
    assert "N" in phones.symbols and phones.phones[0].symbol == "sil"


def test_a_transcript_that_does_not_fit_is_refused_unless_forced(grid_clip, tmp_path):
    wrong = "The quick brown fox jumps over the lazy dog."
    result = run("animate", str(grid_clip), "--text", wrong, "-o", str(tmp_path / "out"))
    assert_clean_error(result)
    assert "does not fit the audio" in result.output and "--force" in result.output
    assert not (tmp_path / "out").exists()
    animate(grid_clip, tmp_path / "forced", "--text", wrong, "--force")
    assert [w.text for w in read_alignment(tmp_path / "forced" / "phones.TextGrid").words][:2] == ["the", "quick"]


def test_transcript_from_sentences_tsv_with_a_named_phone_model(grid_s1, grid_clip, tmp_path):
    texts = dict(line.split("\t") for line in (grid_s1 / "sentences.tsv").read_text().splitlines()[1:])
    animate(grid_clip, tmp_path / "out", "--text", texts[GRID_ID], "--model", "grid-tdnn", "--language", "en")
    jaw = check_outputs(tmp_path / "out", soundfile.info(grid_clip).duration, 16000, textgrid=True)["jawOpen"]
    inside = speech_frames(grid_s1, len(jaw))
    assert jaw[inside].mean() > 2 * jaw[~inside].mean()


def test_transcript_with_an_audio_model(audio_model, grid_clip, tmp_path):
    animate(grid_clip, tmp_path / "out", "--text", GRID_TEXT, "--model", str(audio_model))
    check_outputs(tmp_path / "out", soundfile.info(grid_clip).duration, 16000, textgrid=True)


def test_transcript_in_swedish(tmp_path):
    """Swedish speech (espeak-ng) with its transcript: aligned in Swedish, animated by grid-tdnn."""
    from vispeech.frontends.espeak import synthesize

    speech = synthesize(SWEDISH, "sv")
    path = write_audio(tmp_path / "sv.wav", speech.audio, speech.sample_rate)
    animate(path, tmp_path / "out", "--text", SWEDISH, "--language", "sv")
    check_outputs(tmp_path / "out", speech.duration, speech.sample_rate, textgrid=True)
    phones = read_alignment(tmp_path / "out" / "phones.TextGrid", "sv")
    assert len(phones.words) == 3 and phones.language == "sv"


def test_a_phone_model_without_transcript(grid_clip, tmp_path):
    out = tmp_path / "out"
    assert_clean_error(run("animate", str(grid_clip), "--model", "grid-tdnn", "-o", str(out)))
    assert not out.exists()


# ---- hard audio ---------------------------------------------------------------------------


def test_silence(audio_model, tmp_path):
    """Digital silence animates with the mouth near closed; aligning words with it may fail, cleanly."""
    path = write_audio(tmp_path / "silence.wav", np.zeros(2 * 16000, np.float32), 16000)
    animate(path, tmp_path / "out", "--model", str(audio_model))
    jaw = check_outputs(tmp_path / "out", 2.0, 16000)["jawOpen"]
    assert np.median(jaw) < 0.05
    out = tmp_path / "text"
    result = run("animate", str(path), "--text", GRID_TEXT, "-o", str(out))
    if result.exit_code == 0:
        check_outputs(out, 2.0, 16000, textgrid=True)
    else:
        assert_clean_error(result)
        assert not out.exists()


@pytest.mark.parametrize("kind", ["white noise", "clipped"])
def test_noise_and_clipping(audio_model, grid_s1, tmp_path, kind):
    if kind == "white noise":
        samples = np.random.default_rng(0).uniform(-1, 1, 3 * 16000).astype(np.float32)
    else:
        samples = np.clip(20 * grid_samples(grid_s1), -1, 1)  # about half the samples at full scale
    path = write_audio(tmp_path / "in.wav", samples, 16000)
    animate(path, tmp_path / "out", "--model", str(audio_model))
    check_outputs(tmp_path / "out", len(samples) / 16000, 16000)  # finite, within [0, 1]


def test_ten_minutes(audio_model, grid_s1, tmp_path):
    """The longest audio allowed: 10 minutes of tiled GRID speech at 8 kHz, animated in reasonable time."""
    rate = 8000
    tile = AudioClip.from_array(grid_samples(grid_s1), 16000).resampled(rate).samples
    samples = np.resize(tile, int(MAX_DURATION_S * rate))
    path = write_audio(tmp_path / "long.wav", samples, rate, subtype="PCM_16")
    started = time.perf_counter()
    animate(path, tmp_path / "out", "--model", str(audio_model))
    elapsed = time.perf_counter() - started
    track = check_outputs(tmp_path / "out", MAX_DURATION_S, rate)
    assert track.n_frames == 18000
    assert elapsed < 180, f"10 minutes of audio took {elapsed:.0f} s"  # about 20 s on 2 busy cores


def test_longer_than_ten_minutes(tmp_path):
    path = write_audio(tmp_path / "long.wav", np.zeros(int((MAX_DURATION_S + 1) * 4000), np.int16), 4000)
    out = tmp_path / "out"
    result = run("animate", str(path), "-o", str(out))
    assert_clean_error(result)
    assert "limit is 600 s" in result.stderr and not out.exists()


# ---- bad input: one line, exit code 2, nothing written --------------------------------------


def png_bytes() -> bytes:
    """A valid 1x1 grey PNG image."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00\x80")) + chunk(b"IEND", b""))


def make_bad_input(kind: str, folder: Path) -> Path:
    """A file (or folder) that is no usable audio."""
    if kind == "empty audio":
        return write_audio(folder / "empty.wav", np.zeros(0, np.float32), 16000)
    path = folder / {"PNG": "image.png", "PNG as .wav": "image.wav"}.get(kind, "in.wav")
    if kind == "zero bytes":
        path.write_bytes(b"")
    elif kind == "text as .wav":
        path.write_text("this is not audio\n" * 100)
    elif kind.startswith("PNG"):
        path.write_bytes(png_bytes())
    elif kind == "folder":
        path.mkdir()
    return path  # "missing": nothing there


BAD_INPUTS = ["empty audio", "zero bytes", "text as .wav", "PNG", "PNG as .wav", "missing", "folder"]


@pytest.mark.parametrize("kind", BAD_INPUTS)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, kind):
    bad = make_bad_input(kind, tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out"
    result = run("animate", str(bad), "-o", str(out))
    assert_clean_error(result)
    assert result.stdout == "" and result.stderr.startswith("error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no output folder, no staging folder left


def test_bad_input_keeps_an_earlier_output_folder(audio_model, grid_clip, tmp_path):
    out = tmp_path / "out"
    animate(grid_clip, out, "--model", str(audio_model))
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}
    for kind in BAD_INPUTS:
        bad = tmp_path / kind.replace(" ", "-")
        bad.mkdir()
        assert_clean_error(run("animate", str(make_bad_input(kind, bad)), "-o", str(out)))
        assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier, kind


@pytest.mark.parametrize("args", [["--fps", "0"], ["--model", "nope"], ["--text", "   "],
                                  ["--text", "bin blue at f two now", "--language", "xx"]])
def test_bad_options(grid_clip, tmp_path, args):
    out = tmp_path / "out"
    assert_clean_error(run("animate", str(grid_clip), "-o", str(out), *args))
    assert not out.exists()
