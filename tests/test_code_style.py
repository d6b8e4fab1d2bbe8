"""The house rules hold on src/: ruff's lint and format, and mypy, as pyproject.toml configures them."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(tool: str, *args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    command = shutil.which(tool, path=str(Path(sys.executable).parent)) or tool
    return subprocess.run([command, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args", [("check", "src"), ("format", "--check", "src")], ids=["lint", "format"])
def test_ruff_passes(args):
    result = run("ruff", *args)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-1000:]


def test_mypy_passes():
    result = run("mypy", "--no-incremental", timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-1000:]
