"""``vispeech evaluate`` on synthetic takes and on five real GRID utterances."""

import shutil

import pytest
from click.testing import CliRunner
from conftest import copy_grid_utterances, resample_face_csv
from test_train_cli import synthetic_take, write_takes

from vispeech.cli import main
from vispeech.errors import VispeechError
from vispeech.models.registry import create_model

GRID_TEST_IDS = ["bbaf2n", "bbas3a", "bbbm2p", "bbbmzn", "bgan4n"]  # all in the test split


@pytest.fixture(autouse=True)
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache-home"))


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    return write_takes(tmp_path_factory.mktemp("corpus") / "takes")


def _evaluate(*args):
    return CliRunner().invoke(main, ["evaluate", *map(str, args)])


def test_evaluate_models_and_a_saved_folder_on_takes(takes, tmp_path):
    saved = create_model("baseline", lead_in=0).save(tmp_path / "saved")
    result = _evaluate("--corpus", takes, "--language", "en", "-m", "baseline", "-m", saved,
                       "--channels", "mouthClose", "--postprocessing", "none", "-q",
                       "--markdown", tmp_path / "t.md", "--plot", tmp_path / "p.png", "--plot-utterance", "u19")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    # speech span of a take: 0.2 s to 0.4 s + 80 ms per phone, i.e. frames 5 .. 10 + 2 per phone
    frames = sum(6 + 2 * (len(synthetic_take(i)[0]) - 2) for i in (0, 19))
    assert lines[0] == f"takes:test: 2 utterances, {frames} speech frames at 25 fps, post-processing none"
    rows = [line.split() for line in lines if line.startswith(("baseline", str(saved)))]
    assert [row[:2] for row in rows] == [["baseline", "jawOpen"], ["baseline", "mouthClose"], ["baseline", "(mean)"],
                                         [str(saved), "jawOpen"], [str(saved), "mouthClose"], [str(saved), "(mean)"]]
    assert rows[1][3:] == ["n/a"] * 4  # mouthClose is constant in the recordings: no range, no r
    assert -1 <= float(rows[0][4]) <= 1
    assert "/p b m/" not in result.output  # takes have no landmarks: no closure figures
    markdown = (tmp_path / "t.md").read_text()
    assert markdown.startswith("# Objective evaluation") and "| baseline | jawOpen |" in markdown
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert "jawOpen of u19 ->" in result.output


@pytest.mark.parametrize(("args", "message"), [
    (["-m", "{corrupt}"], "corrupt model config"),
    (["-m", "{missing}"], "nor a saved model folder"),
    (["-m", "baseline", "-m", "baseline"], "given twice"),
    (["-m", "baseline", "--channels", "headYaw"], "does not predict channel 'headYaw'"),
    (["-m", "baseline", "--channels", "lip_aperture"], "has no channel 'lip_aperture'"),
    (["-m", "baseline", "--plot", "{tmp}/p.png", "--plot-utterance", "u01"], "no utterance 'u01'"),
    (["-m", "sliding-window-thesis"], "must be trained first"),
    (["-m", "tdnn-lowlatency"], "must be trained first"),
    (["-m", "baseline", "--language", "xx"], "unknown language 'xx' for phones"),
    (["-m", "baseline", "--markdown", "{corrupt}/config.json/x.md"], "cannot write"),  # before evaluating
])
def test_evaluate_errors_are_one_line(takes, tmp_path, args, message):
    (tmp_path / "corrupt").mkdir()
    (tmp_path / "corrupt" / "config.json").write_text("{")
    places = {"corrupt": tmp_path / "corrupt", "missing": tmp_path / "missing", "tmp": tmp_path}
    result = _evaluate("--corpus", takes, "--language", "en", "-q", *(a.format(**places) for a in args))
    assert result.exit_code == 2
    assert result.output.startswith("error: ") and message in result.output


def test_empty_split_and_bad_corpus(tmp_path):
    train_only = write_takes(tmp_path / "few", ids=["u01", "u02"])
    result = _evaluate("--corpus", train_only, "--language", "en", "-m", "baseline", "-q")
    assert result.exit_code == 2 and "the test split of corpus few has no utterances" in result.output
    result = _evaluate("--corpus", tmp_path / "nowhere", "-m", "baseline")
    assert result.exit_code == 2 and "error: corpus folder not found" in result.output


@pytest.fixture
def grid5(grid_s1, tmp_path):
    src = grid_s1
    texts = dict(line.split("\t") for line in (src / "sentences.tsv").read_text().splitlines()[1:])
    dst = tmp_path / "grid5"
    (dst / "utterances").mkdir(parents=True)
    for uid in GRID_TEST_IDS:
        for ext in ("flac", "align", "csv"):
            shutil.copy(src / "utterances" / f"{uid}.{ext}", dst / "utterances")
    (dst / "sentences.tsv").write_text("id\ttext\n" + "".join(f"{u}\t{texts[u]}\n" for u in GRID_TEST_IDS))
    return dst


def test_evaluate_on_five_grid_utterances(grid5, tmp_path, monkeypatch):
    args = ["--corpus", grid5, "-m", "baseline", "--channels", "jawOpen,mouthClose", "-q"]
    result = _evaluate(*args)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "grid5:test: 5 utterances, 191 speech frames at 25 fps, post-processing auto"
    jaw = next(line.split() for line in lines if line.startswith("baseline  jawOpen"))
    assert float(jaw[4]) > 0.4  # r of jawOpen
    closures = next(line.split() for line in lines if line.startswith("baseline ") and "/" in line)
    closed, scored = map(int, closures[1].split("/"))
    assert scored >= 10 and closed / scored >= 0.9  # the overlays close on tracked /p b m/ closures
    assert closures[4] == "25.1"  # tracked share of closed speech frames

    def no_alignment(*_):
        raise VispeechError("aligned again despite the cache")

    monkeypatch.setattr("vispeech.corpus.alignment.align", no_alignment)
    again = _evaluate(*args)
    assert again.exit_code == 0 and again.output == result.output


def test_transcript_gives_an_audio_model_the_phones(grid5):
    """--transcript: grid-audio-encdec animates the audio blended with the aligned phones, as
    `animate --text` does, so it closes the lips on every tracked /p b m/ the phones mark."""
    outputs = {}
    for flag in ([], ["--transcript"]):
        result = _evaluate("--corpus", grid5, "-m", "grid-audio-encdec", "--channels", "jawOpen", "-q", *flag)
        assert result.exit_code == 0, result.output
        outputs[bool(flag)] = result.output.splitlines()
    jaw = {k: next(line.split() for line in v if line.startswith("grid-audio-encdec  jawOpen"))
           for k, v in outputs.items()}
    assert jaw[True][4] != jaw[False][4] and float(jaw[True][4]) > 0.8
    closures = {k: next(line.split() for line in v if line.startswith("grid-audio-encdec ") and "/" in line)
                for k, v in outputs.items()}
    closed, scored = map(int, closures[True][1].split("/"))
    assert scored >= 10 and closed == scored and int(closures[False][1].split("/")[0]) < scored


def test_the_report_folder_on_five_grid_utterances(grid5, tmp_path):
    """--report writes the HTML page with the ANOVA, the CSV and JSON of every score and the
    figures (PNG and SVG); its numbers are those printed, its ANOVA that of utterances.csv."""
    import csv
    import json

    from vispeech.evaluation.statistics import compare_models

    out = tmp_path / "report"
    result = _evaluate("--corpus", grid5, "-m", "shipped", "-m", "baseline", "--channels", "jawOpen,mouthClose",
                       "--report", out, "--sync", "-q")
    assert result.exit_code == 0, result.output
    names = {p.name for p in out.iterdir()}
    assert {"report.html", "scores.csv", "utterances.csv", "anova.csv", "pairs.csv", "scores.json"} <= names
    for stem in ("correlation", "utterance_rmse", "trajectory"):
        assert (out / f"{stem}.png").read_bytes()[:4] == b"\x89PNG" and b"<svg" in (out / f"{stem}.svg").read_bytes()
    scores = json.loads((out / "scores.json").read_text())
    labels = [m["label"] for m in scores["models"]]
    assert labels == ["grid-tdnn", "grid-tdnn-lowlatency", "grid-cohen-massaro", "grid-ohman", "grid-audio-cnn",
                      "grid-audio-encdec", "grid-audio-whisper", "grid-audio-whisper-base",
                      "grid-audio-whisper-ensemble", "baseline"]
    printed = next(line.split() for line in result.output.splitlines() if line.split()[:2] == ["grid-tdnn", "jawOpen"])
    tdnn = scores["models"][0]["scores"]["jawOpen"]
    assert f"{tdnn['r']:.3f}" == printed[4]
    rows = list(csv.DictReader((out / "utterances.csv").open()))
    assert [r["utterance"] for r in rows] == GRID_TEST_IDS
    per_model = {label: [float(r[f"{label} jawOpen_rmse_percent"]) for r in rows] for label in labels}
    again = compare_models(per_model)
    assert scores["comparison"]["anova"]["f"] == pytest.approx(again.anova.f, rel=1e-4)  # the CSV keeps 6 digits
    assert scores["comparison"]["anova"]["df_model"] == 9 and len(scores["comparison"]["pairs"]) == 45
    page = (out / "report.html").read_text()
    assert "Repeated-measures ANOVA" in page
    assert scores["sync"] == {"model": "grid-tdnn", "lags_s": dict.fromkeys(GRID_TEST_IDS, 0.0)}  # 3-s takes
    assert "Sound and picture re-synced by grid-tdnn: predictions moved by each utterance" in page
    assert 'src="trajectory.png"' in page and "Lip closures" in page and "How jawOpen moves" in page
    dynamics = scores["models"][0]["jawOpen_dynamics"]
    assert abs(dynamics["lag_s"]) <= 0.2 and 0 < dynamics["high_frequency_share"] < 1
    by_phone = scores["models"][0]["jawOpen_rmse_by_phone_class"]
    assert list(by_phone) == ["vowel", "bilabial", "labiodental", "other consonant", "silence"]
    assert all(v is None or 0 <= v < 100 for v in by_phone.values()) and by_phone["vowel"] is not None
    closures = scores["models"][0]["closures"]
    printed = next(line.split() for line in result.output.splitlines() if line.startswith("grid-tdnn ") and "/" in line)
    assert [f"{closures[k]:.1f}" for k in ("model_closed_share", "tracked_closed_share")] == printed[3:5]
    assert closures["onset_median_ms"] is not None and abs(closures["onset_median_ms"]) <= 200
    assert "jawOpen RMSE by phone class" in page and "onset median (ms)" in page and "lip vertex error" in page
    lips = {m["label"]: m["lips"] for m in scores["models"]}
    assert 0 < lips["grid-tdnn"]["floor"] <= lips["grid-tdnn"]["lve"] < lips["baseline"]["lve"] < 0.2


def test_split_all_scores_a_corpus_of_mixed_frame_rates(grid_s1, tmp_path):
    """bbaf2n (test split, 25 fps) and bbaf3s (train split, its track resampled to 30 fps):
    --split all scores both, each on its own frames, with the closures."""
    from vispeech.corpus import read_grid
    from vispeech.evaluation import scored_frames, tracked_closed

    root = copy_grid_utterances(grid_s1, tmp_path / "grid2", 2)
    resample_face_csv(root / "utterances" / "bbaf3s.csv", 30.0)
    corpus = read_grid(root, cache=tmp_path / "unused")
    assert [(u.id, u.track.fps, u.track.n_frames) for u in corpus] == [("bbaf2n", 25.0, 75), ("bbaf3s", 30.0, 90)]
    frames = [int(scored_frames(u).sum()) for u in corpus]
    test_only = _evaluate("--corpus", root, "-m", "baseline", "--channels", "jawOpen", "-q")
    assert test_only.exit_code == 0, test_only.output
    assert test_only.output.splitlines()[0] == (
        f"grid2:test: 1 utterances, {frames[0]} speech frames at 25 fps, post-processing auto")
    result = _evaluate("--corpus", root, "--split", "all", "-m", "baseline", "--channels", "jawOpen", "-q")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == f"grid2:all: 2 utterances, {sum(frames)} speech frames at 25 and 30 fps, post-processing auto"
    jaw = next(line.split() for line in lines if line.startswith("baseline  jawOpen"))
    assert float(jaw[4]) > 0.4
    closures = next(line.split() for line in lines if line.startswith("baseline ") and "/" in line)
    closed = sum(int(tracked_closed(u.landmarks)[scored_frames(u)].sum()) for u in corpus)
    assert closures[1] == "3/3" and closures[4] == f"{100 * closed / sum(frames):.1f}"  # tracked, per own frame
    synced = _evaluate("--corpus", root, "--split", "all", "-m", "baseline", "--channels", "jawOpen", "--sync", "-q")
    assert synced.exit_code == 0, synced.output
    assert synced.output.splitlines()[0] == (  # 3-s takes: too short for their lags to be told
        f"{lines[0]}, re-synced by grid-tdnn: predictions moved by each utterance's lag (median +0 ms, +0 to +0 ms; "
        "0 of 2 moved)")
    assert synced.output.splitlines()[1:] == lines[1:]
    bad = _evaluate("--corpus", root, "--split", "every", "-m", "baseline", "-q")
    assert bad.exit_code == 2 and "'every' is not one of 'train', 'validation', 'test', 'all'" in bad.output
