"""``vispeech batch`` and :mod:`vispeech.batch`: manifests and folders read into lines, outputs
equal to the single commands', resumable reruns, failures that stop nothing, kills that lose
nothing."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_cli_say import SAY_FILES, assert_clean_error, run
from vispeech.batch import JobDefaults, read_job, run_batch
from vispeech.batch.line import RECORD, expected_files
from vispeech.batch.run import INDEX
from vispeech.pipeline import speak, write_outputs

GRID_ID = "bbaf2n"
GRID_TEXT = "bin blue at f two now"


def _csv(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def _jsonl(path: Path, records: list) -> Path:
    path.write_text("".join((r if isinstance(r, str) else json.dumps(r)) + "\n" for r in records), encoding="utf-8")
    return path


def _assert_same_files(a: Path, b: Path, names=SAY_FILES) -> None:
    """The files ``names`` of folders ``a`` and ``b`` are equal byte for byte (espeak-ng speaks
    the same text identically in any process and order: vispeech.frontends.espeak)."""
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def _index(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / INDEX).read_text(encoding="utf-8").splitlines()]


# -- reading jobs ----------------------------------------------------------------------------

def test_csv_manifest_fields_defaults_and_relative_paths(tmp_path):
    (tmp_path / "takes").mkdir()
    job = _csv(tmp_path / "job.csv", [
        "id,text,language,audio,alignment,model,fps,rate,formats,postprocessing",
        'a,"Hello, there.",,,,,,,,',
        "b,Hej då.,sv,,,baseline,60,1.3,csv;json,none",
        "c,bin blue,,takes/c.wav,,,,,,",
        "d,,,,takes/d.TextGrid,,,,livelink json,",
    ])
    lines = read_job(job, JobDefaults(language="en", fps=25.0))
    assert [(x.id, x.kind, x.error) for x in lines] == [
        ("a", "text", None), ("b", "text", None), ("c", "audio", None), ("d", "alignment", None)]
    a, b, c, d = lines
    assert a.text == "Hello, there." and a.language == "en" and a.fps == 25.0 and a.model is None and a.postprocessing == "auto"
    assert a.formats == ("wav", "textgrid", "livelink", "json", "preview")
    assert (b.language, b.model, b.fps, b.rate, b.formats, b.postprocessing) == ("sv", "baseline", 60.0, 1.3, ("livelink", "json"), "none")
    assert c.audio == tmp_path / "takes" / "c.wav" and c.text == "bin blue"
    assert d.alignment == tmp_path / "takes" / "d.TextGrid" and d.language is None  # guessed from its symbols


def test_jsonl_manifest_and_line_errors(tmp_path):
    job = _jsonl(tmp_path / "job.jsonl", [
        {"id": "ok", "text": "Hello.", "formats": ["csv"]},
        "{not json",
        [1, 2],
        {"id": "both", "audio": "x.wav", "alignment": "x.lab"},
        {"id": "nothing"},
        {"id": "lang", "text": "Hi.", "language": "xx"},
        {"id": "fps", "text": "Hi.", "fps": 1000},
        {"id": "fmt", "text": "Hi.", "formats": "csv,mp4"},
        {"id": "../up", "text": "Hi."},
        {"id": "ok", "text": "Again."},
        {"id": "rate", "audio": "x.wav", "rate": 1.2},
        {"id": "extra", "text": "Hi.", "colour": "red"},
        {"text": "No id."},
        {"id": "voiced", "text": "Hi.", "voice": "f3"},
        {"id": "novoice", "text": "Hi.", "voice": "nobody"},
        {"id": "audiovoice", "audio": "x.wav", "voice": "f3"},
        {"id": "raw", "text": "Hi.", "postprocessing": "none"},
        {"id": "old", "text": "Hi.", "postprocess": False},
        {"id": "bool", "text": "Hi.", "postprocessing": False},
        {"id": "silent", "alignment": "x.lab", "formats": "wav preview textgrid"},
    ])
    lines = read_job(job)
    errors = {x.number: x.error for x in lines}
    assert errors[1] is None and lines[0].formats == ("livelink",)  # csv: its alias
    assert "not valid JSON" in errors[2]
    assert "not a JSON object" in errors[3]
    assert "not both" in errors[4]
    assert "no text, audio or alignment" in errors[5]
    assert "unknown language 'xx'" in errors[6]
    assert "fps must be between" in errors[7]
    assert "unknown output format 'mp4'" in errors[8]
    assert "not a folder name" in errors[9]
    assert "used by line 1 already" in errors[10]
    assert "rate is for text lines" in errors[11]
    assert "unknown field 'colour'" in errors[12]
    assert errors[13] is None and lines[12].id == "00013"
    assert errors[14] is None and lines[13].voice == "f3" and lines[0].voice is None
    assert "unknown voice 'nobody'" in errors[15]
    assert "voice is for text lines" in errors[16]
    assert errors[17] is None and lines[16].postprocessing == "none" and lines[0].postprocessing == "auto"
    assert "unknown field 'postprocess'" in errors[18]
    assert "unknown post-processing 'False' (use auto, none or a preset: authored" in errors[19]
    assert "an alignment line has no audio, so none of its formats (wav, preview, textgrid)" in errors[20]


def test_jsonl_errors_name_the_file_line_past_blank_lines(tmp_path):
    job = tmp_path / "blank.jsonl"
    job.write_text('{"id": "a", "text": "Hi."}\n\n\nnot json\n', encoding="utf-8")
    lines = read_job(job)
    assert [x.id for x in lines] == ["a", "00002"]  # the job's second line, on the file's fourth
    assert lines[1].error.startswith("line 4 of blank.jsonl is not valid JSON")


def test_folder_job_reads_texts_recordings_with_transcripts_and_alignments(tmp_path):
    (tmp_path / "greeting.txt").write_text("Hello there.\n", encoding="utf-8")
    (tmp_path / "take.wav").write_bytes(b"RIFF")  # read at run time, not now
    (tmp_path / "take.txt").write_text("bin blue", encoding="utf-8")
    (tmp_path / "line.TextGrid").write_text("x", encoding="utf-8")
    (tmp_path / "notes.md").write_text("not an input", encoding="utf-8")
    (tmp_path / ".hidden.txt").write_text("skip", encoding="utf-8")
    lines = read_job(tmp_path)
    assert [(x.id, x.kind, x.text) for x in lines] == [
        ("greeting", "text", "Hello there."), ("line", "alignment", None), ("take", "audio", "bin blue")]


def test_a_folder_jobs_unreadable_text_fails_its_line_only(tmp_path):
    (tmp_path / "a.txt").write_text("Hello there.", encoding="utf-8")
    (tmp_path / "b.txt").write_text("", encoding="utf-8")
    (tmp_path / "c.txt").write_bytes(b"\xff\xfeA")  # UTF-16 with an odd number of bytes
    (tmp_path / "d.wav").write_bytes(b"RIFF")
    (tmp_path / "d.txt").write_text("", encoding="utf-8")  # its transcript
    lines = read_job(tmp_path)
    assert [(x.number, x.id) for x in lines] == [(1, "a"), (2, "b"), (3, "c"), (4, "d")]
    assert lines[0].error is None and "empty" in lines[1].error and "odd number of bytes" in lines[2].error
    assert "transcript" in lines[3].error and "empty" in lines[3].error


@pytest.mark.parametrize("rows,message", [
    (["id,words", "a,hello"], "unknown column 'words'"),
    (["id,language", "a,en"], "needs a text, audio or alignment column"),
    (["id,text,text", "a,hello,world"], "column 'text' appears twice"),
    (["", "id,text", "a,hello"], "no header line"),
    ([""], "is empty"),
])
def test_unreadable_csv_manifest_is_one_error(tmp_path, rows, message):
    job = _csv(tmp_path / "job.csv", rows)
    result = run("batch", str(job), "-o", str(tmp_path / "out"))
    assert_clean_error(result)
    assert message in result.output
    assert not (tmp_path / "out").exists()


def test_the_root_folder_is_refused_as_a_batch_output(tmp_path):
    job = _csv(tmp_path / "job.csv", ["id,text", "zz_vispeech_test,hello"])
    made = [Path("/zz_vispeech_test"), Path("/index.jsonl")]
    assert not any(p.exists() for p in made)
    try:
        result = run("batch", str(job), "-o", "/")
        assert result.exit_code == 2 and "is the root folder" in result.output
        assert not any(p.exists() for p in made)
    finally:  # what a regression would write into the root folder
        shutil.rmtree(made[0], ignore_errors=True)
        made[1].unlink(missing_ok=True)


def test_missing_or_unknown_job_is_one_error(tmp_path):
    for job in (tmp_path / "missing.csv", _csv(tmp_path / "job.txt", ["hello"])):
        result = run("batch", str(job), "-o", str(tmp_path / "out"))
        assert_clean_error(result)


# -- running ---------------------------------------------------------------------------------

def test_outputs_equal_say_and_rerun_redoes_exactly_what_changed(tmp_path):
    texts = ["Hello, how can I help you today?", "My mom made a large map of the farm.", "Bin blue at F two now."]
    rows = ["id,text,language"] + [f'line{i},"{t}",en' for i, t in enumerate(texts)] + ['hej,"Hej! Hur mår du?",sv']
    job = _csv(tmp_path / "job.csv", rows)
    out = tmp_path / "out"
    report = run_batch(job, out, workers=1)
    assert [r.status for r in report.results] == ["written"] * 4
    for i, text in enumerate(texts):
        folder = out / f"line{i}"
        assert {p.name for p in folder.iterdir()} == SAY_FILES | {RECORD}
        write_outputs(speak(text, "en"), tmp_path / f"said{i}")
        _assert_same_files(folder, tmp_path / f"said{i}")
        record = json.loads((folder / RECORD).read_text())
        assert record["key"] == report.results[i].key and record["text"] == text and record["model"] == "grid-tdnn"
    assert [row["status"] for row in _index(out)] == ["written"] * 4

    again = run_batch(job, out, workers=1)
    assert [r.status for r in again.results] == ["unchanged"] * 4
    before = (out / "line0" / "animation.csv").stat().st_mtime_ns

    rows[2] = 'line1,"My mom made a small map of the farm.",en'  # text changed
    rows[4] = 'hej,"Hej! Hur mår du?",sv'
    _csv(job, rows + ['new,"A new line.",en'])
    (out / "line2" / "preview.html").unlink()  # a file lost: redone
    third = run_batch(job, out, workers=1)
    assert {r.id: r.status for r in third.results} == {
        "line0": "unchanged", "line1": "written", "line2": "written", "hej": "unchanged", "new": "written"}
    assert (out / "line0" / "animation.csv").stat().st_mtime_ns == before

    _jsonl(tmp_path / "job.jsonl", [{"id": "line0", "text": texts[0], "fps": 60}])  # same text, other settings
    assert run_batch(tmp_path / "job.jsonl", out, workers=1).results[0].status == "written"
    assert run_batch(tmp_path / "job.jsonl", out, workers=1, force=True).results[0].status == "written"


def test_failed_lines_are_reported_and_stop_nothing(tmp_path):
    write_outputs(speak("Hello.", "en"), tmp_path / "said")
    job = _jsonl(tmp_path / "job.jsonl", [
        {"id": "first", "text": "Hello there."},
        {"id": "missing", "audio": "nowhere.wav"},
        {"id": "model", "text": "Hi.", "model": "no-such-model"},
        {"id": "notaudio", "audio": "job.jsonl"},
        {"id": "phonemodel", "audio": "said/speech.wav", "model": "grid-tdnn"},
        {"id": "last", "text": "Goodbye.", "formats": "csv"},
    ])
    report = run_batch(job, tmp_path / "out", workers=1)
    status = {r.id: (r.status, r.error) for r in report.results}
    assert status["first"][0] == "written" and status["last"][0] == "written"
    assert "not found" in status["missing"][1]
    assert "unknown model 'no-such-model'" in status["model"][1]
    assert status["notaudio"][0] == "failed" and status["notaudio"][1]
    assert "give the transcript" in status["phonemodel"][1]  # a phone model cannot animate audio alone
    assert {p.name for p in (tmp_path / "out" / "last").iterdir()} == {"animation.csv", RECORD}
    assert not (tmp_path / "out" / "missing").exists()
    assert [row["id"] for row in _index(tmp_path / "out")] == [r.id for r in report.results]

    result = run("batch", str(job), "-o", str(tmp_path / "out"), "-q")
    assert result.exit_code == 1
    assert "2 unchanged, 4 failed" in result.output and "failed: line 2 (missing):" in result.output
    assert "Traceback" not in result.output


def test_audio_and_alignment_lines_match_the_single_commands(tmp_path, grid_s1):
    said = tmp_path / "said"
    write_outputs(speak("My mom made a large map of the farm.", "en"), said)
    audio = grid_s1 / "utterances" / f"{GRID_ID}.flac"
    job = _jsonl(tmp_path / "job.jsonl", [
        {"id": "phones", "alignment": "said/phones.TextGrid", "fps": 25},
        {"id": "take", "audio": str(audio), "text": GRID_TEXT, "formats": ["csv", "textgrid", "wav"]},
        {"id": "heard", "audio": str(audio), "model": "grid-audio-cnn", "formats": "csv json"},
    ])
    report = run_batch(job, tmp_path / "out", workers=1)
    assert [r.status for r in report.results] == ["written"] * 3, report.results
    for result, line in zip(report.results, read_job(job)):
        assert result.files == expected_files(line)
    assert set(report.results[0].files) == {"animation.csv", "animation.json", RECORD}
    assert "phones.TextGrid" in report.results[1].files
    for name in ("phones", "take", "heard"):
        assert run(*_single(name, tmp_path, audio)).exit_code == 0
        ours = (tmp_path / "out" / name / "animation.csv").read_bytes()
        assert ours == (tmp_path / f"single-{name}" / "animation.csv").read_bytes()  # no speech synthesis here


def test_a_transcript_that_does_not_fit_fails_its_line_unless_transcripts_are_trusted(tmp_path, grid_s1):
    audio = grid_s1 / "utterances" / f"{GRID_ID}.flac"
    job = _jsonl(tmp_path / "job.jsonl", [
        {"id": "true", "audio": str(audio), "text": GRID_TEXT, "formats": "csv"},
        {"id": "wrong", "audio": str(audio), "text": "lay white with zed three please", "formats": "csv"},
    ])
    checked = run_batch(job, tmp_path / "checked", workers=1)
    assert [r.status for r in checked.results] == ["written", "failed"]
    assert "the transcript does not fit the audio" in checked.results[1].error
    result = run("batch", str(job), "-o", str(tmp_path / "trusted"), "-q", "-j", "1", "--trust-transcripts")
    assert result.exit_code == 0, result.output
    assert [r["status"] for r in _index(tmp_path / "trusted")] == ["written", "written"]
    same = tmp_path / "checked" / "true" / "animation.csv"
    assert (tmp_path / "trusted" / "true" / "animation.csv").read_bytes() == same.read_bytes()
    forced = run("animate", str(audio), "--text", "lay white with zed three please", "--force", "-o",
                 str(tmp_path / "forced"))
    assert forced.exit_code == 0, forced.output
    wrong = (tmp_path / "trusted" / "wrong" / "animation.csv").read_bytes()
    assert wrong == (tmp_path / "forced" / "animation.csv").read_bytes() != same.read_bytes()


def _single(name: str, tmp_path: Path, audio: Path) -> list[str]:
    out = ["-o", str(tmp_path / f"single-{name}")]
    if name == "phones":
        return ["animate-phones", str(tmp_path / "said" / "phones.TextGrid"), "--fps", "25", *out]
    if name == "take":
        return ["animate", str(audio), "--text", GRID_TEXT, *out]
    return ["animate", str(audio), "--model", "grid-audio-cnn", *out]


def test_parallel_workers_write_what_one_process_writes(tmp_path):
    rows = ["id,text,language"] + [f"l{i},Line number {i} of the batch.,en" for i in range(6)] + ["s,Hej på dig.,sv"]
    job = _csv(tmp_path / "job.csv", rows)
    one = run_batch(job, tmp_path / "one", workers=1)
    two = run_batch(job, tmp_path / "two", workers=2)
    assert [r.key for r in one.results] == [r.key for r in two.results]
    for result in two.results:
        assert result.status == "written"
        _assert_same_files(tmp_path / "two" / result.id, tmp_path / "one" / result.id, SAY_FILES | {RECORD})


def test_lines_run_on_one_blas_thread_and_the_caller_gets_its_threads_back(tmp_path):
    """Lines run side by side, one a core: OpenBLAS's own threads would spin on the cores the
    other lines need."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> set[int]:
        return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}

    job = _csv(tmp_path / "job.csv", ["id,text,language", "a,Hello there.,en", "b,Good morning.,en"])
    with threadpool_limits(2, user_api="blas"):
        during: list[set[int]] = []
        report = run_batch(job, tmp_path / "out", workers=1, progress=lambda _: during.append(blas_threads()))
        assert report.count("written") == 2
        assert during == [{1}, {1}] and blas_threads() == {2}


def test_killed_batch_loses_and_duplicates_nothing(tmp_path):
    n = 40
    job = _csv(tmp_path / "job.csv", ["id,text"] + [f"k{i:02d},This is sentence {i} of a long batch." for i in range(n)])
    out = tmp_path / "out"
    process = subprocess.Popen([sys.executable, "-c", "from vispeech.cli import main; main()", "batch", str(job), "-o", str(out), "-j", "2",
                                "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if out.is_dir() and sum(1 for p in out.iterdir() if not p.name.startswith(".")) >= 5:
            break
        time.sleep(0.05)
    assert process.poll() is None, "the batch ended before it could be killed"
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    done_before = {p.name for p in out.iterdir() if not p.name.startswith(".") and (p / RECORD).is_file()}
    assert 0 < len(done_before) < n
    for name in done_before:  # every folder there is complete
        assert {p.name for p in (out / name).iterdir()} == SAY_FILES | {RECORD}

    report = run_batch(job, out, workers=2)
    status = {r.id: r.status for r in report.results}
    assert {i for i, s in status.items() if s == "unchanged"} == done_before
    assert {i for i, s in status.items() if s == "written"} == {f"k{i:02d}" for i in range(n)} - done_before
    assert sorted(p.name for p in out.iterdir()) == sorted([INDEX, *status])  # nothing half-written left


def test_export_formats_are_written_and_read_back(tmp_path):
    from vispeech.motion.formats.registry import read_track

    job = _jsonl(tmp_path / "job.jsonl", [{"id": "x", "text": "Bob met my mum.", "fps": 60,
                                           "formats": ["json", "oculus", "rhubarb", "talkinghead"]}])
    result = run_batch(job, tmp_path / "out", workers=1).results[0]
    assert result.files == ("animation.json", "animation.talkinghead.json", "animation.visemes.csv", RECORD,
                            "mouth_cues.tsv")
    folder = tmp_path / "out" / "x"
    track = read_track(folder / "animation.json")
    assert track.fps == 60 and read_track(folder / "animation.talkinghead.json").n_frames > 0
    visemes = (folder / "animation.visemes.csv").read_text().splitlines()
    assert visemes[0].split(",")[:3] == ["time", "sil", "PP"] and len(visemes) == track.n_frames + 1
    cues = (folder / "mouth_cues.tsv").read_text().splitlines()
    assert len(cues) > 3 and all(len(line.split("\t")) == 2 for line in cues)


def test_non_verbal_layers_in_a_batch_are_those_say_adds(tmp_path):
    """--life and --seed give every line the layers say gives one text; they are part of the key."""
    import numpy as np
    from click.testing import CliRunner

    from vispeech.cli import main
    from vispeech.motion.formats.livelink import read_livelink_csv

    job = _csv(tmp_path / "job.csv", ["id,text,language", 'one,"Hello there, my friend.",en'])
    runner = CliRunner()
    life = ["--life", "blink,head,expression", "--seed", "4"]
    done = runner.invoke(main, ["batch", str(job), "-o", str(tmp_path / "out"), *life, "--quiet"])
    assert done.exit_code == 0, done.output
    said = runner.invoke(main, ["say", "Hello there, my friend.", "-o", str(tmp_path / "said"), *life])
    assert said.exit_code == 0, said.output
    _assert_same_files(tmp_path / "out" / "one", tmp_path / "said")
    take = read_livelink_csv(tmp_path / "said" / "animation.csv")
    assert np.abs(take["headYaw"]).max() > 0 and take["cheekSquintLeft"].max() > 0  # "friend": a glad face
    again = runner.invoke(main, ["batch", str(job), "-o", str(tmp_path / "out"), "--life", "blink,head,expression",
                                 "--seed", "5", "--quiet"])
    assert again.exit_code == 0 and "1 written" in again.output, again.output  # another seed: redone
