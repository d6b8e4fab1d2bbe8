"""``vispeech corpus info DIR``."""

import shutil

import pytest
from click.testing import CliRunner

from vispeech.cli import main
from vispeech.corpus import split_of


@pytest.fixture
def small_grid(grid_s1, tmp_path, monkeypatch):
    """Two GRID utterances and one listed without its files."""
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache"))
    src = grid_s1
    root = tmp_path / "grid"
    (root / "utterances").mkdir(parents=True)
    for uid in ("bbaf2n", "lrae3s"):
        for ext in ("flac", "align", "csv"):
            shutil.copy(src / "utterances" / f"{uid}.{ext}", root / "utterances")
    (root / "sentences.tsv").write_text(
        "id\ttext\nbbaf2n\tbin blue at f two now\nlrae3s\tlay red at e three soon\nmiss01\tbin red at a one now\n"
    )
    return root


def run(*args):
    return CliRunner().invoke(main, list(args))


def test_corpus_info_without_phones(small_grid):
    result = run("corpus", "info", str(small_grid), "--no-phones")
    assert result.exit_code == 0, result.output
    out = result.output
    assert "utterances: 2 (1 skipped)" in out and "skipped miss01: missing" in out
    assert "fps: 25" in out
    assert "channels (57): browDownLeft," in out and "headYaw" in out
    expected = {name: [split_of("bbaf2n"), split_of("lrae3s")].count(name) for name in ("train", "validation", "test")}
    assert f"splits: train {expected['train']}, validation {expected['validation']}, test {expected['test']}" in out
    duration = (47648 + 47648) / 16000
    assert f"duration: {duration:.1f} s" in out
    assert "phone coverage" not in out


def test_corpus_info_aligns_for_phone_coverage(small_grid, tmp_path):
    result = run("corpus", "info", str(small_grid), "--cache", str(tmp_path / "c"))
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()  # the progress bar goes to stderr
    start = next(i for i, line in enumerate(lines) if line.startswith("phone coverage (2 utterances"))
    counts = dict(line.strip().split("\t") for line in lines[start + 1:] if "\t" in line)
    # bin blue at f two now + lay red at e three soon
    assert counts["sil"] == "4" and counts["B"] == "2" and counts["UW"] == "3" and counts["IY"] == "2"
    missing = next(line for line in lines if line.startswith("missing inventory phones:"))
    assert "ZH" in missing and "OY" in missing and " B," not in missing and "sil" not in missing
    assert sorted(p.name for p in (tmp_path / "c" / "align").iterdir()) == ["bbaf2n.json", "lrae3s.json"]


def test_corpus_info_strict_and_missing_folder(small_grid, tmp_path):
    result = run("corpus", "info", str(small_grid), "--strict", "--no-phones")
    assert result.exit_code == 2
    assert result.output.strip() == "error: skipped miss01: missing miss01.flac, miss01.align, miss01.csv"
    result = run("corpus", "info", str(tmp_path / "nothing"))
    assert result.exit_code == 2 and result.output.startswith("error: corpus folder not found")
    result = run("corpus", "info", str(small_grid), "-l", "xx")  # before anything is read or aligned
    assert result.exit_code == 2
    assert result.output.strip() == "error: unknown language 'xx' for phones (use sv, en or ipa)"


def test_corpus_info_sync_names_the_take_whose_picture_is_late(small_grid):
    import csv

    path = small_grid / "utterances" / "bbaf2n.csv"
    with path.open(newline="") as f:
        header, *rows = list(csv.reader(f))
    late = 3  # frames: the picture shows each moment 120 ms after its sound
    moved = [row[:2] + rows[max(k - late, 0)][2:] for k, row in enumerate(rows)]
    with path.open("w", newline="") as f:
        csv.writer(f).writerows([header, *moved])
    result = run("corpus", "info", str(small_grid), "--no-phones", "--sync")
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    header = next(line for line in lines if line.startswith("A/V sync (+: the picture late;"))
    assert header.endswith("1 of 2 takes measured (the others lack lip landmarks or last under 3 s)")  # lrae3s: 2.96 s
    assert "1 off by more than a frame: re-sync or leave them out before training" in result.stdout
    listed = [line.split("\t") for line in lines if "\t" in line]
    assert [name.strip() for name, _ in listed] == ["bbaf2n"]
    assert abs(float(listed[0][1].removesuffix(" ms")) - 120) < 40
