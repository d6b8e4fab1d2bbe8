"""Output folders are replaced as a whole: a kill -9 at any point leaves the old folder or the new one.

The crash tests fork a child that runs :func:`vispeech.pipeline.write_outputs` and kills itself
with SIGKILL just before its N-th file-system call (open, write, fsync, mkdir, chmod, rename,
exchange, unlink, rmdir), for every N until a run gets through; after each kill the folder must
be exactly the old complete set or the new complete set, and the next run must leave no junk.
"""

from __future__ import annotations

import fcntl
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vispeech import files
from vispeech.alignment.formats import read_alignment
from vispeech.cli import main
from vispeech.motion.track import Track
from vispeech.pipeline import animate, write_outputs, write_outputs_many
from vispeech.utterance import Utterance

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
        intervals: size = 4
        intervals [1]:
            xmin = 0
            xmax = 0.2
            text = "sil"
        intervals [2]:
            xmin = 0.2
            xmax = 0.5
            text = "{first}"
        intervals [3]:
            xmin = 0.5
            xmax = 0.8
            text = "AA1"
        intervals [4]:
            xmin = 0.8
            xmax = 1.0
            text = "sil"
"""
SAY_FILES = {"speech.wav", "phones.TextGrid", "animation.csv", "animation.json", "preview.html"}
_OPS = ("open", "write", "fsync", "mkdir", "chmod", "rename", "replace", "unlink", "rmdir")


def _utterance(tmp_path: Path, first: str, audio: bool) -> Utterance:
    grid = tmp_path / f"{first}.TextGrid"
    grid.write_text(TEXTGRID.format(first=first))
    phones = read_alignment(grid, "en")
    track = animate(phones, "baseline", 30.0)
    if not audio:
        return Utterance(text="", phones=phones, track=track)
    samples = (0.1 * np.sin(np.arange(16000) * 0.05)).astype(np.float32)
    return Utterance(text=f"say {first}", phones=phones, track=track, audio=samples, sample_rate=16000)


def _snapshot(folder: Path) -> dict[str, bytes] | None:
    if not folder.exists():
        return None
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _recover(parent: Path) -> None:
    """What the next run does first: clean up (and restore) what killed runs left."""
    with files._parent_lock(parent) as locked:
        assert locked
        files._clean_stale(parent)


def _kill_at(n: int) -> None:
    """In a forked child: SIGKILL this process just before its n-th file-system call."""
    count = [0]

    def wrap(func):
        def wrapper(*args, **kwargs):
            count[0] += 1
            if count[0] >= n:
                os.kill(os.getpid(), signal.SIGKILL)
            return func(*args, **kwargs)
        return wrapper

    for name in _OPS:
        setattr(os, name, wrap(getattr(os, name)))
    io.open = wrap(io.open)
    import builtins
    builtins.open = io.open
    files._exchange = wrap(files._exchange)
    syncfs = files._syncfs_function()
    if syncfs is not None:
        files._syncfs_function = lambda: wrap(syncfs)


def _run_killed(n: int, write, exchange: bool) -> bool:
    """Run ``write()`` in a child killed at its n-th call; True if it was killed."""
    pid = os.fork()
    if pid == 0:  # the child
        code = 1
        try:
            if not exchange:
                files._swap_function = False
            _kill_at(n)
            write()
            code = 0
        finally:
            os._exit(code)
    deadline = time.monotonic() + 20
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail(f"child killed at call {n} hung")
        time.sleep(0.002)
    if os.WIFSIGNALED(status):
        assert os.WTERMSIG(status) == signal.SIGKILL
        return True
    assert os.WEXITSTATUS(status) == 0, f"child failed at call {n}"
    return False


@pytest.mark.parametrize("exchange,start", [(True, "old"), (False, "old"), (True, "none")],
                         ids=["exchange", "two-renames", "first-run"])
def test_a_kill_at_any_point_leaves_the_old_or_the_new_folder(tmp_path, exchange, start):
    if exchange and not files._exchange_function():
        pytest.skip("no renameat2 here")
    old_utt = _utterance(tmp_path, "P", audio=True)   # what `say` wrote
    new_utt = _utterance(tmp_path, "M", audio=False)  # what `animate-phones` writes over it
    reference = tmp_path / "reference"
    write_outputs(new_utt, reference / "new")
    write_outputs(old_utt, reference / "old")
    new, old = _snapshot(reference / "new"), _snapshot(reference / "old")
    assert set(new) == {"animation.csv", "animation.json"} and set(old) == SAY_FILES
    parent = tmp_path / "work"
    out = parent / "out"
    seen = set()
    for n in range(1, 400):
        if out.exists():
            files.shutil.rmtree(out)
        if start == "old":
            files.shutil.copytree(reference / "old", out)  # as `say` left it
        parent.mkdir(exist_ok=True)
        killed = _run_killed(n, lambda: write_outputs(new_utt, out), exchange)
        state = _snapshot(out)
        if exchange and start == "old":
            assert state in (old, new), f"killed at call {n}: {sorted(state or ())}"
        else:  # between the two renames, or before the first run's one, the folder is missing
            assert state in (old, new, None), f"killed at call {n}: {sorted(state or ())}"
        _recover(parent)  # the next run's clean-up
        state = _snapshot(out)
        assert state in ((old, new) if start == "old" else (new, None)), f"killed at call {n}, recovered"
        assert sorted(os.listdir(parent)) == (["out"] if state is not None else []), f"junk after call {n}"
        seen.add("new" if state == new else "old" if state == old else "none")
        if not killed:
            break
    else:
        pytest.fail("write_outputs never finished")
    print(f"{n - 1} kill points")
    assert n > 15  # every call of a whole run (17 of them with no old folder) was a kill point
    assert seen >= ({"old", "new"} if start == "old" else {"none", "new"})
    write_outputs(new_utt, out)  # and the next run writes the new folder, leaving nothing else
    assert _snapshot(out) == new and os.listdir(parent) == ["out"]


def test_phones_into_a_say_folder_leave_no_stale_files(tmp_path):
    out = tmp_path / "hello"
    write_outputs(_utterance(tmp_path, "P", audio=True), out)
    grid = tmp_path / "take.TextGrid"
    grid.write_text(TEXTGRID.format(first="M"))
    result = CliRunner().invoke(main, ["animate-phones", str(grid), "--model", "baseline", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} == {"animation.csv", "animation.json"}
    assert sorted(os.listdir(tmp_path)) == ["P.TextGrid", "hello", "take.TextGrid"]


def test_a_folder_holding_other_files_is_not_replaced(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    (out / "animation.csv").write_text("old")
    grid = tmp_path / "take.TextGrid"
    grid.write_text(TEXTGRID.format(first="M"))
    result = CliRunner().invoke(main, ["animate-phones", str(grid), "--model", "baseline", "-o", str(out)])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "notes.txt" in lines[0], result.output
    assert _snapshot(out) == {"notes.txt": b"keep me", "animation.csv": b"old"}
    assert sorted(os.listdir(tmp_path)) == ["mine", "take.TextGrid"]


@pytest.mark.parametrize("command", ["animate-phones", "animate"])
def test_a_folder_holding_the_input_is_not_replaced(tmp_path, command):
    """The edited phones.TextGrid (or the speech.wav) of a folder `say` wrote, animated back into
    that folder, would go with it: refused before any work, the folder left as it was."""
    out = tmp_path / "hello"
    write_outputs(_utterance(tmp_path, "P", audio=True), out)
    before = _snapshot(out)
    given = out / ("phones.TextGrid" if command == "animate-phones" else "speech.wav")
    result = CliRunner().invoke(main, [command, str(given), "--model", "baseline", "-o", str(out)])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "holds the input" in lines[0], result.output
    assert _snapshot(out) == before


def test_an_empty_folder_is_replaced_and_a_file_is_an_error(tmp_path):
    utterance = _utterance(tmp_path, "M", audio=False)
    (tmp_path / "empty").mkdir()
    write_outputs(utterance, tmp_path / "empty")
    assert {p.name for p in (tmp_path / "empty").iterdir()} == {"animation.csv", "animation.json"}
    (tmp_path / "file").write_text("x")
    with pytest.raises(files.VispeechError, match="not a folder"):
        write_outputs(utterance, tmp_path / "file")
    with pytest.raises(files.VispeechError, match="not a folder"), files.atomic_output_dir(tmp_path / "file"):
        pass
    assert (tmp_path / "file").read_text() == "x"


def test_a_symlinked_output_folder_is_replaced_where_it_leads(tmp_path):
    utterance = _utterance(tmp_path, "M", audio=False)
    real = tmp_path / "real"
    write_outputs(_utterance(tmp_path, "P", audio=True), real)
    (tmp_path / "link").symlink_to(real)
    write_outputs(utterance, tmp_path / "link")
    assert (tmp_path / "link").is_symlink()
    assert {p.name for p in real.iterdir()} == {"animation.csv", "animation.json"}


def test_only_stale_leftovers_of_vispeech_are_removed(tmp_path):
    parent = tmp_path / "p"
    parent.mkdir()
    (parent / ".vispeech-dead.lock").write_text('{"target": "gone"}')
    (parent / ".vispeech-dead.tmp").mkdir()
    (parent / ".vispeech-dead.tmp" / "animation.csv").write_text("half")
    (parent / ".vispeech-dead2.part").write_text("half")
    (parent / ".vispeech-notours").mkdir()  # no lock file: not ours to remove
    (parent / "user.txt").write_text("keep")
    live = parent / ".vispeech-live.lock"
    live.write_text('{"target": "busy"}')
    (parent / ".vispeech-live.tmp").mkdir()
    with open(live, "r+") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)  # a run in progress
        write_outputs(_utterance(tmp_path, "M", audio=False), parent / "out")
    assert sorted(os.listdir(parent)) == [".vispeech-live.lock", ".vispeech-live.tmp", ".vispeech-notours",
                                          "out", "user.txt"]
    write_outputs(_utterance(tmp_path, "M", audio=False), parent / "out")  # the live run has gone now
    assert sorted(os.listdir(parent)) == [".vispeech-notours", "out", "user.txt"]


def test_a_model_folder_with_its_checkpoint_is_replaced_whole(tmp_path):
    from vispeech.models.registry import create_model, load_folder

    out = tmp_path / "model"
    model = create_model("ohman")
    model.save(out / "checkpoint")  # vispeech train keeps a checkpoint inside its output folder
    (out / "checkpoint" / "training_state.json").write_text("{}")
    model.save(out / "checkpoint")
    model.save(out)
    assert sorted(os.listdir(out)) == ["config.json"]
    assert load_folder(out).family == "ohman"
    (out / "mine.txt").write_text("x")
    with pytest.raises(files.VispeechError, match="mine.txt"):
        model.save(out)
    assert sorted(os.listdir(tmp_path)) == ["model"]


def test_a_killed_cli_run_leaves_a_complete_folder(tmp_path):
    """`vispeech animate-phones` over a `say` folder, killed with SIGKILL after spread-out delays."""
    grid = tmp_path / "take.TextGrid"
    grid.write_text(TEXTGRID.format(first="M"))
    out = tmp_path / "work" / "out"
    old_utt = _utterance(tmp_path, "P", audio=True)
    command = [str(Path(sys.executable).parent / "vispeech"), "animate-phones", str(grid), "--model", "baseline",
               "-o", str(out)]
    write_outputs(old_utt, out)
    old = _snapshot(out)
    started = time.monotonic()
    subprocess.run(command, check=True, capture_output=True, timeout=60)
    whole = time.monotonic() - started
    new = _snapshot(out)
    assert set(new) == {"animation.csv", "animation.json"}
    for k in range(8):
        files.shutil.rmtree(out)
        write_outputs(old_utt, out)
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(whole * (0.55 + 0.06 * k))  # the writing comes at the end, after start-up
        process.send_signal(signal.SIGKILL)
        process.wait()
        assert _snapshot(out) in (old, new), f"killed after {whole * (0.55 + 0.06 * k):.3f} s"
        _recover(out.parent)
        assert os.listdir(out.parent) == ["out"]


def test_the_current_folder_is_not_replaced(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(files.VispeechError, match="current folder"):
        write_outputs(_utterance(tmp_path, "M", audio=False), ".")
    with pytest.raises(files.VispeechError, match="current folder"):
        write_outputs(_utterance(tmp_path, "M", audio=False), tmp_path.parent)
    assert sorted(os.listdir(tmp_path)) == ["M.TextGrid"]


def test_concurrent_runs_into_one_folder_leave_one_complete_folder(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    utterances = [_utterance(tmp_path, "P", audio=True), _utterance(tmp_path, "M", audio=False)]
    reference = []
    for k, utterance in enumerate(utterances):
        write_outputs(utterance, tmp_path / f"ref{k}")
        reference.append(_snapshot(tmp_path / f"ref{k}"))
    out = tmp_path / "work" / "out"
    with ThreadPoolExecutor(4) as pool:
        list(pool.map(lambda k: write_outputs(utterances[k % 2], out), range(16)))
    assert _snapshot(out) in reference
    assert os.listdir(out.parent) == ["out"]


def test_a_kill_at_any_point_of_a_batch_leaves_each_folder_old_or_new(tmp_path):
    """write_outputs_many over two `say` folders and a new one, killed before each of its
    file-system calls (the one syncfs included): each folder is its old or new complete self."""
    if not files._exchange_function():
        pytest.skip("no renameat2 here")
    old_utt, new_utt = _utterance(tmp_path, "P", audio=True), _utterance(tmp_path, "M", audio=False)
    write_outputs(new_utt, tmp_path / "reference" / "new")
    write_outputs(old_utt, tmp_path / "reference" / "old")
    new, old = _snapshot(tmp_path / "reference" / "new"), _snapshot(tmp_path / "reference" / "old")
    parent = tmp_path / "work"
    outs = [parent / "a", parent / "b", parent / "c"]
    seen = set()
    for n in range(1, 600):
        files.shutil.rmtree(parent, ignore_errors=True)
        for out in outs[:2]:
            files.shutil.copytree(tmp_path / "reference" / "old", out)
        killed = _run_killed(n, lambda: write_outputs_many([new_utt] * 3, outs), exchange=True)
        for recovered in (False, True):
            states = [_snapshot(out) for out in outs]
            assert states[0] in (old, new) and states[1] in (old, new), f"killed at call {n}, {recovered=}"
            assert states[2] in (new, None), f"killed at call {n}, {recovered=}"
            _recover(parent)
        assert sorted(os.listdir(parent)) == [o.name for o, state in zip(outs, states) if state], f"junk after {n}"
        seen.add(tuple(state == new for state in states))
        if not killed:
            break
    else:
        pytest.fail("write_outputs_many never finished")
    assert n > 30 and {(False, False, False), (True, True, True)} <= seen
    assert all(_snapshot(out) == new for out in outs)


def test_a_batch_writes_every_folder_it_can_and_reports_the_others(tmp_path):
    """A folder of the user's and a track with nothing to write are reported in their places and
    left as they were; the other folders get the bytes write_outputs gives each alone."""
    utterances = [_utterance(tmp_path, first, audio=False) for first in ("M", "P", "F")]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    nothing = Utterance(phones=utterances[0].phones, track=Track(np.zeros((30, 1)), ("headNod",), 30.0))
    outs = [tmp_path / "a", mine, tmp_path / "c", tmp_path / "d"]
    results = write_outputs_many([utterances[0], utterances[1], nothing, utterances[2]], outs)
    assert results[0] == [tmp_path / "a" / "animation.csv", tmp_path / "a" / "animation.json"]
    assert isinstance(results[1], files.VispeechError) and "notes.txt" in str(results[1])
    assert isinstance(results[2], files.VispeechError) and "Live Link" in str(results[2])
    assert _snapshot(mine) == {"notes.txt": b"keep me"}
    assert sorted(os.listdir(tmp_path)) == ["F.TextGrid", "M.TextGrid", "P.TextGrid", "a", "d", "mine"]
    for utterance, out in ((utterances[0], "a"), (utterances[2], "d")):
        write_outputs(utterance, tmp_path / "alone" / out)
        assert _snapshot(tmp_path / out) == _snapshot(tmp_path / "alone" / out)


def test_a_batch_that_fails_otherwise_leaves_every_folder_untouched(tmp_path):
    old = _utterance(tmp_path, "P", audio=True)
    outs = [tmp_path / "work" / name for name in "ab"]
    for out in outs:
        write_outputs(old, out)
    before = [_snapshot(out) for out in outs]

    def write(i: int, folder: Path) -> None:
        (folder / "animation.csv").write_text("half")
        if i == 1:
            raise RuntimeError("a bug")

    with pytest.raises(RuntimeError, match="a bug"):
        files.write_output_dirs(outs, write)
    assert [_snapshot(out) for out in outs] == before
    assert sorted(os.listdir(tmp_path / "work")) == ["a", "b"]
