"""The command group: commands load on demand, missing extras are one line, start-up stays light."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

import vispeech.cli
from vispeech.cli import main
from vispeech.motion.formats.livelink import write_livelink_csv
from vispeech.motion.track import Track

EXTRA_MODULES = ("torch", "matplotlib", "pocketsphinx", "tqdm", "fastapi", "starlette", "uvicorn", "websockets")
"""What no core command may import before it needs it (the train and serve extras)."""


def test_every_command_is_listed_and_lives_where_the_group_looks():
    listed = main.list_commands(click.Context(main))
    for path in Path(vispeech.cli.__file__).parent.glob("*.py"):
        if not path.name.startswith("_"):
            importlib.import_module(f"vispeech.cli.{path.stem}")
    assert sorted(main.commands) == listed
    assert {"say", "animate-phones", "convert", "align", "corpus", "evaluate", "train", "rig", "serve",
            "stream"} <= set(listed)


def test_help_lists_every_command():
    result = CliRunner().invoke(main, ["--help"])
    assert result.exit_code == 0, result.output
    for name in main.list_commands(click.Context(main)):
        assert f"  {name} " in result.output, name


def test_every_language_option_is_language(tmp_path):
    """The same option name everywhere (and no other spelling); the same default (en) wherever there is one."""
    for name in main.list_commands(click.Context(main)):
        command = main.get_command(click.Context(main), name)
        commands = command.commands.values() if isinstance(command, click.Group) else [command]
        for sub in commands:
            for param in sub.params:
                assert not {"--lang", "--languages"} & set(param.opts), (name, sub.name)
                if "--language" in param.opts:
                    assert param.opts == ["--language", "-l"] or param.opts == ["-l", "--language"], (name, param.opts)
                    assert param.default == ("en" if sub.name != "animate-phones" else None), (sub.name, param.default)


def test_a_missing_extra_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "uvicorn", None)  # import uvicorn raises ModuleNotFoundError
    result = CliRunner().invoke(main, ["serve"])
    assert result.exit_code == 2
    assert result.output.strip() == 'error: vispeech serve needs uvicorn, which is not installed: pip install "vispeech[serve]"'


def test_preparing_a_head_without_scipy_names_the_rig_extra(monkeypatch, tmp_path, shared_dir):
    """The core has no SciPy; `rig prepare` needs it and says which extra brings it."""
    for name in ["scipy", *(m for m in sys.modules if m.startswith("scipy."))]:
        monkeypatch.setitem(sys.modules, name, None)
    head = tmp_path / "head.glb"
    result = CliRunner().invoke(main, ["rig", "prepare", str(shared_dir / "assets/ict_head.glb"), "-o", str(head)])
    assert result.exit_code == 2
    assert result.output.strip() == 'error: vispeech rig needs scipy, which is not installed: pip install "vispeech[rig]"'
    assert not head.exists()


def _imported_by(args: list[str], cwd: Path) -> set[str]:
    """The top-level modules a fresh process imported to run ``vispeech ARGS``."""
    script = (
        "import sys\nfrom vispeech.cli import main\n"
        f"try:\n    main({args!r})\nexcept SystemExit as exc:\n    assert not exc.code, exc.code\n"
        "print('\\n' + __import__('json').dumps(sorted({m.partition('.')[0] for m in sys.modules})))\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    result = subprocess.run([sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, env=env,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    return set(json.loads(result.stdout.strip().splitlines()[-1]))


def test_start_up_imports_no_extra(tmp_path):
    """--help and convert (CSV to JSON) import nothing from the extras, nor pygltflib."""
    write_livelink_csv(Track(np.zeros((3, 1)), ("jawOpen",), 30.0), tmp_path / "in.csv")
    light = {*EXTRA_MODULES, "pygltflib"}
    assert not _imported_by(["--help"], tmp_path) & light
    assert not _imported_by(["convert", "in.csv", "out.json"], tmp_path) & light
    assert (tmp_path / "out.json").is_file()


@pytest.mark.parametrize("url,expected", [
    ("http://127.0.0.1:8000", "ws://127.0.0.1:8000/api/listen"),
    ("https://example.org/", "wss://example.org/api/listen"),
    ("ws://host:1/api/stream", "ws://host:1/api/stream"),
    ("http://host/api/listen?token=x", "ws://host/api/listen?token=x"),
])
def test_stream_takes_http_addresses(url, expected):
    from vispeech.cli.stream import websocket_url

    assert websocket_url(url, "listen") == expected


def test_stream_refuses_other_urls():
    result = CliRunner().invoke(main, ["stream", "hello", "--url", "ftp://host/x"])
    assert result.exit_code == 2 and "--url" in result.output and "Traceback" not in result.output


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """``vispeech languages | head -2`` printed "error: Broken pipe" and exited 2: a pipe's reader
    that has read enough is no error. Exit 141 (SIGPIPE's), nothing on stderr, as Unix tools do."""
    import subprocess
    import sys

    process = subprocess.Popen([sys.executable, "-c", "from vispeech.cli import main; main()", "languages"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()  # gone before the first line: the first write fails
    assert process.stderr.read() == b"" and process.wait(60) == 141
    # a socket as standard output (a service's) reports its reader gone with POLLHUP, as macOS's pipes do
    import socket

    ours, theirs = socket.socketpair()
    process = subprocess.Popen([sys.executable, "-c", "from vispeech.cli import main; main()", "languages"],
                               stdout=theirs.fileno(), stderr=subprocess.PIPE)
    theirs.close()
    ours.close()
    assert process.stderr.read() == b"" and process.wait(60) == 141
    # another pipe breaking (a worker's) while stdout is fine is an error like any other
    script = ("from vispeech.cli import main\n@main.command('boom')\ndef boom():\n"
              "    raise BrokenPipeError(32, 'Broken pipe')\nmain()")
    done = subprocess.run([sys.executable, "-c", script, "boom"], capture_output=True, timeout=60)
    assert done.returncode == 2 and done.stderr == b"error: Broken pipe\n", done.stderr
