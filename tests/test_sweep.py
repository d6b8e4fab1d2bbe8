"""``vispeech sweep``: one trained model per look-ahead or window, and the figure."""

from __future__ import annotations

import csv
import json

import pytest
from click.testing import CliRunner
from test_train_cli import synthetic_take, write_takes

from conftest import require_module
from vispeech.cli import main

require_module("torch", "torch (the train extra)")


@pytest.fixture(autouse=True)
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache-home"))


def test_a_look_ahead_sweep_trains_a_model_per_value(tmp_path):
    takes = write_takes(tmp_path / "takes")
    out = tmp_path / "sweep"
    result = CliRunner().invoke(main, [
        "sweep", "look-ahead", "--corpus", str(takes), "--language", "en", "--values", "0,3", "-o", str(out),
        "--param", "epochs=2", "--param", "hidden=4", "--param", "fps=null", "--param", "batch_size=4"])
    assert result.exit_code == 0, result.output
    assert "look_ahead=0: jawOpen RMSE" in result.output and "look_ahead=3" in result.output
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [int(r["value"]) for r in rows] == [0, 3] and all(0 < float(r["rmse_percent"]) < 100 for r in rows)
    saved = json.loads((out / "sweep.json").read_text())
    assert saved["family"] == "tdnn-lowlatency" and saved["parameter"] == "look_ahead" and saved["params"]["epochs"] == 2
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG" and b"<svg" in (out / "sweep.svg").read_bytes()
    # fps=null: the models ran at the takes' rate, the unit of the values (the figure's x axis says so)
    assert [p["fps"] for p in saved["points"]] == [synthetic_take(0)[1].fps] * 2


@pytest.mark.parametrize(("args", "message"), [
    (["--values", "a,b"], "whole numbers"),
    (["--values", "-1"], "none negative"),
    (["--values", "1", "--param", "epochs"], "KEY=VALUE"),
    # refused before any model is trained (the first value's would be, were it checked one by one)
    (["--values", "2,2", "--param", "epochs=1"], "look_ahead=2 is given twice"),
    (["--values", "0", "--param", "epochs=1", "-o", "mine"], "holds files vispeech did not write"),
])
def test_bad_sweeps_are_one_line_errors(tmp_path, args, message):
    takes = write_takes(tmp_path / "takes")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    out = ["-o", str(tmp_path / "out")] if "-o" not in args else []
    args = [str(tmp_path / "mine") if a == "mine" else a for a in args]
    result = CliRunner().invoke(main, ["sweep", "look-ahead", "--corpus", str(takes), "--language", "en", *args, *out])
    assert result.exit_code == 2 and message in result.output, result.output
    assert "jawOpen RMSE" not in result.output  # nothing was trained


def test_a_window_sweep_checks_every_value_before_training_any(tmp_path):
    takes = write_takes(tmp_path / "takes")
    result = CliRunner().invoke(main, ["sweep", "window", "--corpus", str(takes), "--language", "en", "--values", "5,4",
                                       "--param", "epochs=1", "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and "windows must satisfy" in result.output, result.output
    assert "jawOpen RMSE" not in result.output and not (tmp_path / "out").exists()
