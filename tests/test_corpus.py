"""Corpus readers (GRID, Live Link takes), splits, cache, missing frames, articulatory parameters."""

import json
import shutil
import warnings

import numpy as np
import pytest
import soundfile
from conftest import resample_face_csv

from vispeech import PhoneSequence, Track, VispeechError
from vispeech.alignment.formats import write_textgrid
from vispeech.alignment.phones import Phone, Word
from vispeech.corpus import (
    ARTICULATORY_CHANNELS, SPLITS, CorpusCache, CorpusWarning, Utterance, align_corpus, articulatory_parameters,
    read_corpus, read_grid, read_takes, split_of,
)
from vispeech.corpus.alignment import cache_key
from vispeech.corpus.corpus import common_frame_rate, frame_rates_text
from vispeech.corpus.grid import fill_missing_frames
from vispeech.motion.formats.livelink import LIVELINK_CHANNELS, write_livelink_csv

GRID_IDS = ["bbaf2n", "bbizzn", "lrae3s"]  # bbizzn: 12 untracked frames first; lrae3s: 74 rows


@pytest.fixture(autouse=True)
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache-home"))
    return tmp_path / "cache-home"


@pytest.fixture
def grid_src(grid_s1):
    return grid_s1


def make_grid(src, dst, ids, extra_sentences=()):
    """A small GRID folder with the utterances ``ids`` copied from ``src``."""
    texts = dict(line.split("\t") for line in (src / "sentences.tsv").read_text().splitlines()[1:])
    (dst / "utterances").mkdir(parents=True)
    for uid in ids:
        for ext in ("flac", "align", "csv"):
            shutil.copy(src / "utterances" / f"{uid}.{ext}", dst / "utterances" / f"{uid}.{ext}")
    rows = [f"{uid}\t{texts[uid]}" for uid in ids] + list(extra_sentences)
    (dst / "sentences.tsv").write_text("id\ttext\n" + "\n".join(rows) + "\n")
    return dst


def test_grid_reader_on_real_utterances(grid_src, tmp_path):
    corpus = read_grid(make_grid(grid_src, tmp_path / "g", GRID_IDS))
    assert corpus.ids == GRID_IDS and corpus.language == "en" and not corpus.problems
    assert corpus.fps == 25.0
    assert len(corpus.channels) == 57 and {"jawOpen", "mouthClose", "headYaw", "headZ"} <= set(corpus.channels)
    assert not any(c.startswith("lm") for c in corpus.channels)
    u = corpus["bbaf2n"]
    assert u.text == "bin blue at f two now"
    assert [w.text for w in u.words] == u.text.split()
    assert u.words[0].start == pytest.approx(23750 / 25000) and u.words[-1].end == pytest.approx(53000 / 25000)
    assert u.duration == pytest.approx(47648 / 16000)
    assert u.track.n_frames == 75 and u.frame_mask.all()
    indices = (13, 14, 78, 308, 0, 17, 61, 291, 37, 267, 84, 314, 152, 148, 377, 1, 33, 263, 10)
    assert set(u.landmarks) == {f"lm{k}" for k in indices}
    assert u.landmarks["lm13"].shape == (75, 3)
    # first row of the CSV: jawOpen 0.0337 and lm13_x
    first = (grid_src / "utterances" / "bbaf2n.csv").read_text().splitlines()[:2]
    header, row = first[0].split(","), first[1].split(",")
    assert u.track["jawOpen"][0] == float(row[header.index("jawOpen")])
    assert u.landmarks["lm13"][0, 0] == float(row[header.index("lm13_x")])
    samples, rate = u.load_audio()
    assert rate == 16000 and samples.shape == (47648,) and np.abs(samples).max() <= 1
    assert corpus["lrae3s"].track.n_frames == 74
    assert corpus.duration == pytest.approx(sum(x.duration for x in corpus))


def test_grid_utterances_keep_their_own_frame_rates(grid_src, tmp_path):
    root = make_grid(grid_src, tmp_path / "g", GRID_IDS)
    resample_face_csv(root / "utterances" / "bbaf2n.csv", 30.0)  # times written with 4 decimals: 0.0333, ...
    corpus = read_grid(root)
    assert corpus.ids == GRID_IDS and not corpus.problems
    assert corpus["bbaf2n"].track.fps == 30.0 and corpus["bbaf2n"].track.n_frames == 90
    assert corpus["bbaf2n"].landmarks["lm13"].shape == (90, 3) and corpus["bbaf2n"].frame_mask.shape == (90,)
    assert [u.track.fps for u in corpus][1:] == [25.0, 25.0] and corpus["lrae3s"].track.n_frames == 74
    assert corpus.frame_rates == (25.0, 30.0) and corpus.fps == 25.0  # the rate most utterances have
    assert "25 and 30 fps" in repr(corpus) and corpus.split("train").frame_rates == (25.0,)
    csv = root / "utterances" / "lrae3s.csv"
    csv.write_text(csv.read_text().replace("headZ", "headW", 1))
    with pytest.warns(CorpusWarning, match="skipped lrae3s: its track's columns differ"):
        assert read_grid(root).ids == GRID_IDS[:2]


def test_common_frame_rate_and_its_text():
    tracks = [Track(np.zeros((3, 1)), ("jawOpen",), fps) for fps in (30.0, 25.0, 29.9999, 25.0004, 60.0)]
    assert common_frame_rate(tracks, 60.0) == 25.0  # 25.0 and 30.0 twice each: the lower
    assert common_frame_rate(tracks[:1], 60.0) == 30.0 and common_frame_rate([], 60.0) == 60.0
    assert [frame_rates_text(r) for r in ((25.0,), (25.0, 30.0), (24.0, 25.0, 29.97))] == [
        "25", "25 and 30", "24, 25 and 29.97"]


def test_grid_untracked_frames_are_filled_and_masked(grid_src, tmp_path):
    u = read_grid(make_grid(grid_src, tmp_path / "g", ["bbizzn"]))["bbizzn"]
    assert np.flatnonzero(~u.frame_mask).tolist() == list(range(12))
    np.testing.assert_array_equal(u.track.values[:12], np.repeat(u.track.values[12:13], 12, axis=0))
    np.testing.assert_array_equal(u.landmarks["lm14"][:12], np.repeat(u.landmarks["lm14"][12:13], 12, axis=0))
    assert np.all(np.isfinite(u.track.values))


def test_fill_missing_frames_interpolates_inside_and_holds_edges():
    nan = np.nan
    values = np.array([[nan, nan], [1.0, 10.0], [nan, nan], [nan, 5.0], [4.0, 40.0], [nan, nan]])
    filled, mask = fill_missing_frames(values)
    assert mask.tolist() == [False, True, False, False, True, False]
    np.testing.assert_allclose(filled[:, 0], [1, 1, 2, 3, 4, 4])
    np.testing.assert_allclose(filled[:, 1], [10, 10, 20, 30, 40, 40])  # a partial row counts as missing


def test_grid_bad_utterances_are_skipped_by_name(grid_src, tmp_path):
    root = make_grid(grid_src, tmp_path / "g", ["bbaf2n", "bbizzn", "lrae3s"],
                     extra_sentences=["gone01\tbin blue at a one now", "blank1\t "])
    (root / "utterances" / "bbizzn.csv").unlink()
    align = root / "utterances" / "lrae3s.align"
    align.write_text(align.read_text().replace(" red", " blue"))
    with pytest.warns(CorpusWarning) as caught:
        corpus = read_grid(root)
    messages = [str(w.message) for w in caught]
    assert corpus.ids == ["bbaf2n"]
    assert len(corpus.problems) == 4 and messages == corpus.problems
    assert any("bbizzn" in m and "bbizzn.csv" in m for m in messages)
    assert any("lrae3s" in m and "differ" in m for m in messages)
    assert any("gone01" in m and "missing" in m for m in messages)
    assert any("blank1" in m and "empty transcript" in m for m in messages)
    with pytest.raises(VispeechError, match="bbizzn"):
        read_grid(root, strict=True)


def test_grid_rejects_unreadable_csv_and_mismatched_lengths(grid_src, tmp_path):
    root = make_grid(grid_src, tmp_path / "g", ["bbaf2n", "bbizzn"])
    (root / "utterances" / "bbaf2n.csv").write_text("frame,time,jawOpen\n0,0.0,abc\n1,0.04,0.1\n")
    csv = root / "utterances" / "bbizzn.csv"
    csv.write_text("\n".join(csv.read_text().splitlines()[:40]) + "\n")  # 39 frames = 1.56 s of 2.98 s
    with pytest.warns(CorpusWarning):
        corpus = read_grid(root)
    assert len(corpus) == 0
    assert "bbaf2n" in corpus.problems[0] and "bbaf2n.csv" in corpus.problems[0]
    assert "bbizzn" in corpus.problems[1] and "1.56 s" in corpus.problems[1]


def test_splits_are_deterministic_disjoint_and_80_10_10():
    ids = [f"utt{i:05d}" for i in range(20000)]
    first = [split_of(i) for i in ids]
    assert first == [split_of(i) for i in ids]
    shares = {name: first.count(name) / len(ids) for name in SPLITS}
    assert shares["train"] == pytest.approx(0.8, abs=0.015)
    assert shares["validation"] == pytest.approx(0.1, abs=0.01)
    assert shares["test"] == pytest.approx(0.1, abs=0.01)


def test_corpus_split_partitions_the_corpus(grid_src, tmp_path):
    corpus = read_grid(make_grid(grid_src, tmp_path / "g", GRID_IDS))
    template = corpus[0]
    corpus.utterances = [Utterance(f"x{i}", "a", template.audio_path, 1.0, template.track) for i in range(60)]
    parts = {name: corpus.split(name) for name in SPLITS}
    seen = [u.id for part in parts.values() for u in part]
    assert sorted(seen) == sorted(corpus.ids) and len(set(seen)) == len(seen)
    for name, part in parts.items():
        assert all(split_of(u.id) == name for u in part)
        assert part.fps == corpus.fps and part.channels == corpus.channels
    everything = corpus.split("all")  # an evaluation-only corpus is scored whole
    assert everything.ids == corpus.ids and everything.name == "g:all" and not everything.problems
    # membership depends on the id only, not on what else the corpus holds
    corpus.utterances = corpus.utterances[::2]
    assert corpus.split("test").ids == [i for i in parts["test"].ids if i in corpus.ids]
    with pytest.raises(VispeechError, match="unknown split"):
        corpus.split("dev")


def test_cache_round_trips_atomically(tmp_path, cache_home):
    cache = CorpusCache.for_corpus("demo", "abc123")
    assert cache.folder == cache_home / "demo-abc123"
    assert CorpusCache.for_corpus("demo", "abc123", tmp_path / "mine").folder == tmp_path / "mine"
    assert cache.read_json("align/u1") is None and cache.read_arrays("feat/u1") is None
    cache.write_json("align/u1", {"text": "hej", "x": [1, 2]})
    assert cache.read_json("align/u1") == {"text": "hej", "x": [1, 2]}
    arrays = {"a": np.arange(6.0).reshape(2, 3), "mask": np.array([True, False])}
    cache.write_arrays("feat/u1", arrays)
    back = cache.read_arrays("feat/u1")
    assert set(back) == {"a", "mask"} and all(np.array_equal(back[k], arrays[k]) for k in arrays)
    assert sorted(p.name for p in cache.folder.rglob("*")) == ["align", "feat", "u1.json", "u1.npz"]
    with pytest.raises(VispeechError):
        cache.write_arrays("feat/bad", {"o": np.array([{"a": 1}], dtype=object)})
    with pytest.raises(VispeechError, match="invalid cache key"):
        cache.write_json("../escape", {})
    assert cache_key("take 1/ä") != cache_key("take_1__") and cache_key("bbaf2n") == "align/bbaf2n"


def test_grid_cache_folder_follows_the_content(grid_src, tmp_path, cache_home):
    root = make_grid(grid_src, tmp_path / "g", ["bbaf2n"])
    first = read_grid(root).cache.folder
    assert first.parent == cache_home and first.name.startswith("g-")
    assert read_grid(root).cache.folder == first
    make_grid(grid_src, tmp_path / "h", ["bbaf2n", "lrae3s"])
    assert read_grid(tmp_path / "h").cache.folder.name != first.name.replace("g-", "h-")
    assert read_grid(root, cache=tmp_path / "c").cache.folder == tmp_path / "c"


def test_align_corpus_caches_per_utterance(grid_src, tmp_path, monkeypatch):
    corpus = read_grid(make_grid(grid_src, tmp_path / "g", ["bbaf2n"]), cache=tmp_path / "c")
    with pytest.raises(VispeechError, match="align the corpus first"):
        corpus.phone_coverage()
    align_corpus(corpus, progress=False)
    phones = corpus["bbaf2n"].phones
    assert [w.text for w in phones.words] == corpus["bbaf2n"].text.split()
    entry = json.loads((tmp_path / "c" / "align" / "bbaf2n.json").read_text())
    assert entry["text"] == "bin blue at f two now" and entry["aligner"].startswith("pocketsphinx")
    coverage = corpus.phone_coverage()
    assert coverage["B"] == 2 and coverage["UW"] == 2 and coverage["sil"] == 2 and sum(coverage.values()) == 16

    # read again: phones come from the cache, the aligner is not called
    def no_alignment(*args, **kwargs):
        raise AssertionError("aligned again despite the cache")

    monkeypatch.setattr("vispeech.corpus.alignment.align", no_alignment)
    again = align_corpus(read_grid(tmp_path / "g", cache=tmp_path / "c"), progress=False)
    assert again["bbaf2n"].phones == phones

    # the same transcript in another language is aligned again: English phones are no Swedish ones
    swedish = read_grid(tmp_path / "g", cache=tmp_path / "c")
    swedish.language = "sv"
    monkeypatch.setattr("vispeech.corpus.alignment.align", lambda *a: (_ for _ in ()).throw(VispeechError("sv!")))
    with pytest.warns(CorpusWarning, match="bbaf2n: sv!"):
        align_corpus(swedish, progress=False)

    # a changed transcript is aligned again; a failure is a named warning (strict: an error)
    corpus = read_grid(tmp_path / "g", cache=tmp_path / "c")
    corpus["bbaf2n"].text = "bin blue at f three now"
    monkeypatch.setattr("vispeech.corpus.alignment.align", lambda *a: (_ for _ in ()).throw(VispeechError("boom")))
    with pytest.warns(CorpusWarning, match="bbaf2n: boom"):
        align_corpus(corpus, progress=False)
    assert corpus["bbaf2n"].phones is None and corpus.problems == ["cannot align bbaf2n: boom"]
    with pytest.raises(VispeechError, match="bbaf2n: boom"):
        align_corpus(corpus, progress=False, strict=True)


def _take_track(seconds, fps=60.0, seed=0):
    rng = np.random.default_rng(seed)
    n = int(round(seconds * fps))
    return Track(rng.uniform(0, 1, (n, len(LIVELINK_CHANNELS))), LIVELINK_CHANNELS, fps)


def _write_take(folder, name, seconds=1.5, text="hej på dig", fps=60.0, textgrid=None):
    write_livelink_csv(_take_track(seconds, fps), folder / f"{name}.csv", start_timecode="10:00:00:00")
    soundfile.write(folder / f"{name}.wav", np.zeros(int(seconds * 16000), dtype=np.float32), 16000)
    if textgrid is not None:
        write_textgrid(textgrid, folder / f"{name}.TextGrid")
    elif text is not None:
        (folder / f"{name}.txt").write_text(text, encoding="utf-8")


def test_takes_reader_reads_and_skips_bad_takes(tmp_path):
    folder = tmp_path / "takes"
    folder.mkdir()
    _write_take(folder, "take01", text="Hej  på\ndig!")
    grid = PhoneSequence(
        [Phone("sil", 0.0, 0.2), Phone("h", 0.2, 0.3, 0), Phone("E", 0.3, 0.5, 0, 1), Phone("j", 0.5, 0.6, 0),
         Phone("sil", 0.6, 1.5)], "sv", [Word("hej", 0.2, 0.6)],
    )
    _write_take(folder, "take02", textgrid=grid)
    _write_take(folder, "take03", text="   ")                       # empty transcript
    _write_take(folder, "take04")
    (folder / "take04.wav").unlink()                                 # no audio
    _write_take(folder, "take05")
    (folder / "take05.csv").write_text("not,a,live link file\n")     # unreadable CSV
    _write_take(folder, "take06", seconds=1.5)
    soundfile.write(folder / "take06.wav", np.zeros(16000 * 4, dtype=np.float32), 16000)  # 4 s audio, 1.5 s track
    _write_take(folder, "take07", fps=30.0)                          # another frame rate

    with pytest.warns(CorpusWarning) as caught:
        corpus = read_takes(folder)
    assert corpus.ids == ["take01", "take02"] and corpus.language == "sv"
    assert corpus.fps == 60.0 and corpus.channels == LIVELINK_CHANNELS
    for name, reason in [("take03", "empty transcript"), ("take04", "take04.wav"), ("take05", "take05.csv"),
                         ("take06", "4.00 s"), ("take07", "30 fps")]:
        assert any(name in str(w.message) and reason in str(w.message) for w in caught), (name, corpus.problems)
    assert len(corpus.problems) == 5

    first = corpus["take01"]
    assert first.text == "Hej på dig!" and first.phones is None and first.words == []
    assert first.track.start_time == 0.0 and first.track.n_frames == 90
    np.testing.assert_allclose(first.track.values, _take_track(1.5).values, atol=1e-9)
    assert first.duration == pytest.approx(1.5) and first.landmarks is None
    second = corpus["take02"]
    assert second.text == "hej" and second.phones.symbols == grid.symbols and second.words == grid.words

    with pytest.raises(VispeechError, match="take03"):
        read_takes(folder, strict=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorpusWarning)
        assert read_corpus(folder).ids == corpus.ids
    with pytest.raises(VispeechError, match="silent"), pytest.warns(CorpusWarning):  # Swedish aligns by DTW; this take is silence
        align_corpus(read_takes(folder), progress=False, strict=True)


def test_english_take_is_aligned(grid_src, tmp_path):
    folder = tmp_path / "takes"
    folder.mkdir()
    samples, rate = soundfile.read(grid_src / "utterances" / "bbaf2n.flac")
    soundfile.write(folder / "bin.wav", samples, rate)
    (folder / "bin.txt").write_text("Bin blue at F two now.")
    write_livelink_csv(_take_track(3.0), folder / "bin.csv")
    corpus = align_corpus(read_takes(folder, language="en", cache=tmp_path / "c"), progress=False)
    assert [w.text for w in corpus["bin"].phones.words] == ["bin", "blue", "at", "f", "two", "now"]
    assert (tmp_path / "c" / "align" / "bin.json").is_file()


def test_read_corpus_detects_grid_and_rejects_other_folders(grid_src, tmp_path):
    root = make_grid(grid_src, tmp_path / "g", ["bbaf2n"])
    assert read_corpus(root).ids == ["bbaf2n"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(VispeechError, match="no takes"):
        read_corpus(tmp_path / "empty")
    with pytest.raises(VispeechError, match="not found"):
        read_corpus(tmp_path / "absent")


def test_articulatory_parameters_ignore_head_motion(grid_src, tmp_path):
    u = read_grid(make_grid(grid_src, tmp_path / "g", ["bbaf2n"]))["bbaf2n"]
    params = articulatory_parameters(u)
    assert params.channels == ARTICULATORY_CHANNELS and params.n_frames == 75 and params.fps == 25.0
    times = params.times
    speaking = np.zeros(len(times), bool)
    for w in u.words:
        speaking |= (times >= w.start) & (times < w.end)
    aperture = params["lip_aperture"]
    assert aperture[speaking].mean() > 5 * np.median(aperture[times < 0.5])  # mouth opens during words
    assert 0.8 < params["jaw_opening"].mean() < 1.3 and 0.4 < params["lip_width"].mean() < 0.8
    assert np.all(params["protrusion"] > 0)

    # rotate the head by 20 degrees (yaw and roll), move it and bring it 30 % closer: same parameters
    size = np.array([360.0, 288.0, 360.0])
    yaw, roll = np.radians(20), np.radians(-15)
    rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]) @ np.array(
        [[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]])
    center = np.array([180.0, 144.0, 0.0])
    moved = {k: (((v * size - center) @ rot.T) * 1.3 + center + [12, -8, 3]) / size for k, v in u.landmarks.items()}
    u.landmarks = moved
    np.testing.assert_allclose(articulatory_parameters(u).values, params.values, atol=1e-9)

    u.landmarks = None
    with pytest.raises(VispeechError, match="no face landmarks"):
        articulatory_parameters(u)
