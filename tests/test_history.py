"""Commits keep the house habit from the day it was set (issue 23): a subject of at most 72
characters saying what changes, and a body saying why. Older history is left as it was."""

import shutil
import subprocess
from datetime import datetime
from pathlib import Path

from conftest import require

ROOT = Path(__file__).resolve().parents[1]
HABIT_SINCE = datetime.fromisoformat("2026-12-03T07:00:00+00:00")
"""Commits made from then on must follow the habit (the first made under it: 1215f80)."""
MAX_SUBJECT = 72


def test_commit_messages_have_short_subjects_and_bodies():
    require(shutil.which("git") is not None and (ROOT / ".git").exists(), "a git checkout of the project")
    log = subprocess.run(["git", "log", "--format=%h%x00%cI%x00%s%x00%b%x1e"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    bad = []
    for entry in filter(str.strip, log.split("\x1e")):
        commit, date, subject, body = entry.strip("\n").split("\x00")
        if datetime.fromisoformat(date) < HABIT_SINCE:
            continue
        if len(subject) > MAX_SUBJECT or not body.strip():
            bad.append(f"{commit} ({len(subject)} characters{'' if body.strip() else ', no body'}): {subject}")
    assert not bad, "commits without a short subject and a body:\n" + "\n".join(bad)
