"""``vispeech say`` / ``animate-phones`` end to end, and their answers to bad input."""

import json
import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from vispeech.cli import main

SAY_FILES = {"speech.wav", "phones.TextGrid", "animation.csv", "animation.json", "preview.html"}


def run(*args):
    return CliRunner().invoke(main, list(args))


def assert_clean_error(result):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.strip().splitlines() if line]
    assert len(lines) == 1 and "error" in lines[0].lower() and "Traceback" not in result.output, result.output


@pytest.mark.parametrize("lang,text", [("sv", "Hej! Hur kan jag hjälpa dig idag?"), ("en", "Hello, how can I help you today?")])
def test_say_writes_every_file(tmp_path, lang, text):
    out = tmp_path / "hello"
    result = run("say", text, "--language", lang, "-o", str(out))
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} == SAY_FILES
    animation = json.loads((out / "animation.json").read_text())
    assert "jawOpen" in animation["channels"] and animation["frames"]
    header = (out / "animation.csv").read_text().splitlines()[0].split(",")
    assert len(header) == 2 + 61  # Timecode, BlendshapeCount, then the 61 values
    assert header[:2] == ["Timecode", "BlendshapeCount"]
    assert (out / "animation.csv").read_text().splitlines()[1].startswith("00:00:00:00")


def test_say_without_text_speaks_the_greeting(tmp_path):
    result = run("say", "-o", str(tmp_path / "g"))
    assert result.exit_code == 0, result.output
    assert (tmp_path / "g" / "speech.wav").stat().st_size > 10_000


@pytest.mark.parametrize("text", ["", "   \n\t "])
def test_empty_text(tmp_path, text):
    out = tmp_path / "o"
    assert_clean_error(run("say", text, "-o", str(out)))
    assert not out.exists() or not any(out.iterdir())


def test_unknown_language(tmp_path):
    assert_clean_error(run("say", "hello", "--language", "xx", "-o", str(tmp_path / "o")))


def test_unknown_model(tmp_path):
    assert_clean_error(run("say", "hello", "--model", "nope", "-o", str(tmp_path / "o")))


def test_unwritable_output_keeps_nothing_half_written(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("keep me")
    assert_clean_error(run("say", "hello", "-o", str(blocker / "sub")))
    assert blocker.read_text() == "keep me"


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_read_only_output_folder(tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o500)
    assert_clean_error(run("say", "hello", "-o", str(out)))


def test_existing_outputs_survive_a_failed_run(tmp_path):
    out = tmp_path / "o"
    assert run("say", "Hello there", "-o", str(out)).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert_clean_error(run("say", "   ", "-o", str(out)))
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


TEXTGRID = """File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 1.0
tiers? <exists>
size = 1
item []:
    item [1]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 1.0
        intervals: size = 5
        intervals [1]:
            xmin = 0
            xmax = 0.2
            text = ""
        intervals [2]:
            xmin = 0.2
            xmax = 0.35
            text = "M"
        intervals [3]:
            xmin = 0.35
            xmax = 0.6
            text = "AA1"
        intervals [4]:
            xmin = 0.6
            xmax = 0.75
            text = "{last}"
        intervals [5]:
            xmin = 0.75
            xmax = 1.0
            text = "sil"
"""


def test_animate_phones_writes_csv_and_json(tmp_path):
    grid = tmp_path / "x.TextGrid"
    grid.write_text(TEXTGRID.format(last="P"))
    out = tmp_path / "anim"
    result = run("animate-phones", str(grid), "--fps", "25", "--model", "cohen-massaro", "-o", str(out))
    assert result.exit_code == 0, result.output
    rows = (out / "animation.csv").read_text().splitlines()
    assert len(rows) - 1 == 25  # one row per frame over 1.0 s
    assert rows[1].startswith("00:00:00:00")
    assert json.loads((out / "animation.json").read_text())["fps"] == 25


@pytest.mark.parametrize("content", ["", "this is not a textgrid", TEXTGRID.format(last="QQ")])
def test_bad_alignments(tmp_path, content):
    grid = tmp_path / "bad.TextGrid"
    grid.write_text(content)
    out = tmp_path / "o"
    assert_clean_error(run("animate-phones", str(grid), "-o", str(out)))
    assert not out.exists() or not any(out.iterdir())


def test_missing_alignment_file(tmp_path):
    assert_clean_error(run("animate-phones", str(tmp_path / "none.TextGrid"), "-o", str(tmp_path / "o")))


@pytest.mark.parametrize("command", [["say", "Hello."], ["animate-phones", "ALIGNMENT"], ["animate", "AUDIO"]])
def test_a_refused_output_folder_stops_the_command_before_any_work(tmp_path, monkeypatch, command):
    import vispeech.cli.animate
    import vispeech.cli.say

    def no_work(*args, **kwargs):
        raise AssertionError("work began before the output folder was checked")

    for module in (vispeech.cli.say, vispeech.cli.animate):
        for name in ("speak", "animate", "listen"):
            if hasattr(module, name):
                monkeypatch.setattr(module, name, no_work)
    monkeypatch.setattr("vispeech.alignment.formats.read_alignment", no_work)
    monkeypatch.setattr("vispeech.frontends.audio.AudioClip.read", no_work)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("a user's file", encoding="utf-8")
    args = [tmp_path / "x.TextGrid" if a == "ALIGNMENT" else tmp_path / "x.wav" if a == "AUDIO" else a for a in command]
    result = run(*map(str, args), "-o", str(out))
    assert_clean_error(result)
    assert "holds files vispeech did not write (notes.txt)" in result.output
    assert (out / "notes.txt").read_text(encoding="utf-8") == "a user's file"


def test_say_reads_a_text_file(tmp_path):
    text = "# Welcome\n\nThis is a **long** text,\nread from a file 🙂.\n"
    (tmp_path / "reply.md").write_text(text, encoding="utf-8")
    result = run("say", "--text-file", str(tmp_path / "reply.md"), "-o", str(tmp_path / "out"))
    assert result.exit_code == 0, result.output
    from vispeech.alignment.formats import read_alignment

    words = [w.text for w in read_alignment(tmp_path / "out" / "phones.TextGrid", "en").words]
    assert words == ["Welcome", "This", "is", "a", "long", "text", "read", "from", "a", "file"]
    for args, message in [(["Hello.", "--text-file", str(tmp_path / "reply.md")], "not both"),
                          (["--text-file", str(tmp_path / "missing.txt")], "missing.txt"),
                          (["--text-file", str(tmp_path)], "")]:
        result = run("say", *args, "-o", str(tmp_path / "bad"))
        assert_clean_error(result)
        assert message in result.output and not (tmp_path / "bad").exists()


def test_bytes_that_are_not_utf8(tmp_path):
    """In an argument they are refused (the shell passes 0xff on as U+DCFF); in a file they are Latin-1."""
    result = run("say", "Hello \udcff world", "-o", str(tmp_path / "arg"))
    assert_clean_error(result)
    assert "lone surrogate U+DCFF at character 7 (the byte 0xff, which is not UTF-8)" in result.output
    assert not (tmp_path / "arg").exists()
    (tmp_path / "latin.txt").write_bytes(b"Hello \xff world")
    result = run("say", "--text-file", str(tmp_path / "latin.txt"), "-o", str(tmp_path / "file"))
    assert result.exit_code == 0, result.output
    from vispeech.alignment.formats import read_alignment

    words = [w.text for w in read_alignment(tmp_path / "file" / "phones.TextGrid", "en").words]
    assert words[0] == "Hello" and words[-1] == "world"


def test_a_grid_word_alignment_points_to_animate_text(tmp_path):
    """GRID's .align files time words: animate-phones says so and names `animate --text`."""
    words = tmp_path / "bbaf2n.align"
    words.write_text("0 23750 sil\n23750 29500 bin\n29500 34000 blue\n34000 74500 sil\n")
    result = run("animate-phones", str(words), "-o", str(tmp_path / "o"))
    assert_clean_error(result)
    assert "'bin'" in result.output and "vispeech animate AUDIO --text" in result.output
