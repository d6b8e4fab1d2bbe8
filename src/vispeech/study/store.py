"""A study's participants and answers in SQLite.

Every change is one transaction (write-ahead log, ``synchronous = FULL``): an answer the
server has acknowledged is on disk, so a crash or a kill of the server loses none, and a
participant who comes back (the same cookie or the same ``pid``) goes on at their next trial.

A participant is known by a keyed hash (HMAC-SHA256 with the store's own secret) of the key
they came with, a recruitment platform's participant id (``?pid=``) or a random one, so
platform ids are not stored; one key gives one response set: a finished participant cannot
start again.

:meth:`StudyStore.export` writes the answers in the layout ``vispeech study analyse`` reads
(``answers.csv``, one row per answer, per face on a rating trial) and one row per participant
(``participants.csv``: intro answers, whether the checks were passed).
"""

from __future__ import annotations

import csv
import hashlib
import hmac
import io
import json
import os
import secrets
import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import cast

from vispeech.errors import VispeechError
from vispeech.study.answers import ANSWER_COLUMNS, PAIRWISE_ANSWERS, RATINGS
from vispeech.study.config import Study, Trial, plan_trials

MAX_MS = 24 * 3600 * 1000
"""The longest time to an answer accepted (ms)."""

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS participants (
    id TEXT PRIMARY KEY, seed INTEGER NOT NULL, plan TEXT NOT NULL, intro TEXT NOT NULL,
    started_at TEXT NOT NULL, finished_at TEXT);
CREATE TABLE IF NOT EXISTS answers (
    participant TEXT NOT NULL REFERENCES participants(id), trial INTEGER NOT NULL, answer TEXT NOT NULL,
    ms INTEGER NOT NULL, answered_at TEXT NOT NULL, PRIMARY KEY (participant, trial));
"""


class StudyError(VispeechError):
    """A request the study refuses; ``status`` is the HTTP status it answers with."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Participant:
    """A participant's plan and progress."""

    id: str
    trials: list[Trial]
    answered: int
    finished: bool


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


class StudyStore:
    """The answers of ``study`` in the SQLite file ``path`` (created if missing; with ``create``
    false it must be a study database already: what an export reads is never made one)."""

    def __init__(self, path: str | os.PathLike, study: Study, *, create: bool = True) -> None:
        self.path = Path(path)
        self.study = study
        try:
            db = sqlite3.connect(self.path, timeout=30)
            try:
                tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
                if not create and not {"meta", "participants", "answers"} <= tables:
                    raise VispeechError(f"{self.path} is not a study database (it has no study's answers)")
                db.execute("PRAGMA journal_mode = WAL")
                db.executescript(_SCHEMA)
            finally:
                db.close()
        except sqlite3.DatabaseError as exc:
            raise VispeechError(f"{self.path} is not a study database: {exc}") from None
        self._secret = bytes.fromhex(self._meta("secret", secrets.token_hex(32)))
        self._check_design(record=create)

    def _check_design(self, record: bool) -> None:
        """Refuse a study whose trials differ from those the stored participants were given (its
        clips, their models, the tasks' models, pairs and warm-ups, the checks or the seed
        changed): their next trials would name clips or models that are gone, or answers would
        land on other models. With ``record``, a file nobody joined yet takes the study as it now
        is (a file from before designs were recorded, with participants, is left as it was)."""
        study = self.study
        design = study.model_dump(
            include={"clips": {"__all__": {"sentence", "models"}}, "checks": True, "seed": True},
            mode="json",
        )
        design["rating"] = study.rating and study.rating.model_dump(include={"models", "warmup"}, mode="json")
        design["pairwise"] = study.pairwise and study.pairwise.model_dump(include={"pairs", "warmup"}, mode="json")
        digest = hashlib.sha256(json.dumps(design, sort_keys=True).encode("utf-8")).hexdigest()
        with self._transaction() as db:
            joined = db.execute("SELECT COUNT(*) FROM participants").fetchone()[0]
            stored = db.execute("SELECT value FROM meta WHERE key = 'design'").fetchone()
            if stored is not None and stored[0] != digest and joined:
                raise VispeechError(
                    f"{self.path} holds the answers of {joined} participant{'s' * (joined != 1)} of another version of "
                    "this study (its clips, models, tasks, checks or seed have changed since): serve the version they "
                    "joined, or give the new one its own --db"
                )
            if record and not joined:
                db.execute("INSERT OR REPLACE INTO meta VALUES ('design', ?)", (digest,))

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """A connection inside one immediate transaction: committed on success, rolled back on error."""
        db = sqlite3.connect(self.path, timeout=30, isolation_level=None)
        try:
            db.execute("PRAGMA synchronous = FULL")
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
        finally:
            db.close()

    def _meta(self, key: str, default: str) -> str:
        """The value stored under ``key``, storing ``default`` first if there is none."""
        with self._transaction() as db:
            db.execute("INSERT OR IGNORE INTO meta VALUES (?, ?)", (key, default))
            return db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()[0]

    def participant_id(self, key: str) -> str:
        """The stored id of the participant who came with ``key``."""
        return hmac.new(self._secret, key.encode("utf-8"), hashlib.sha256).hexdigest()[:32]

    def join(self, key: str, intro: dict[str, str]) -> Participant:
        """The participant with ``key``: a new one (their trials drawn, their ``intro`` answers
        checked and stored) or, unfinished, the same one again. Refused (409) once finished."""
        questions = {q.id: q for q in self.study.questions}
        unknown = set(intro) - set(questions)
        if unknown:
            raise StudyError(f"unknown intro question: {min(unknown)}", 422)
        for qid, question in questions.items():
            if intro.get(qid) not in question.choices:
                raise StudyError(f"intro question {qid!r} needs one of: {', '.join(question.choices)}", 422)
        pid = self.participant_id(key)
        with self._transaction() as db:
            found = _load(db, pid)
            if found is None:
                seed = self.study.seed * 1_000_003 + db.execute("SELECT COUNT(*) FROM participants").fetchone()[0]
                trials = plan_trials(self.study, seed)
                db.execute(
                    "INSERT INTO participants VALUES (?, ?, ?, ?, ?, NULL)",
                    (pid, seed, json.dumps([t.to_json() for t in trials]), json.dumps(intro), _now()),
                )
                found = Participant(pid, trials, 0, False)
        return _unfinished(found)

    def rejoin(self, pid: str) -> Participant | None:
        """The participant with the stored id ``pid`` (a returning browser's), or None when
        there is none. Refused (409) once finished."""
        found = self.participant(pid)
        return None if found is None else _unfinished(found)

    def participant(self, pid: str) -> Participant | None:
        """The participant with the stored id ``pid``, or None."""
        with self._transaction() as db:
            return _load(db, pid)

    def answer(self, pid: str, trial: int, answer: int | str | Sequence[int], ms: int) -> Participant:
        """Store ``pid``'s ``answer`` to their trial number ``trial`` (their next one: 409
        otherwise) after ``ms`` milliseconds; committed before it returns."""
        with self._transaction() as db:
            found = _load(db, pid)
            if found is None:
                raise StudyError("unknown participant: start the study first", 404)
            if found.finished or trial != found.answered:
                raise StudyError(
                    f"trial {trial} is not the next one (trial {found.answered} is)"
                    if not found.finished
                    else "every trial is already answered",
                    409,
                )
            value = _checked_answer(found.trials[trial], answer)
            if not 0 <= int(ms) <= MAX_MS:
                raise StudyError(f"ms must lie between 0 and {MAX_MS}", 422)
            now = _now()
            db.execute("INSERT INTO answers VALUES (?, ?, ?, ?, ?)", (pid, trial, json.dumps(value), int(ms), now))
            finished = trial + 1 == len(found.trials)
            if finished:
                db.execute("UPDATE participants SET finished_at = ? WHERE id = ?", (now, pid))
        return Participant(pid, found.trials, trial + 1, finished)

    def export(self) -> tuple[str, str]:
        """``answers.csv`` and ``participants.csv`` (see the module docstring) as text."""
        with self._transaction() as db:
            people = db.execute(
                "SELECT id, plan, intro, started_at, finished_at FROM participants ORDER BY started_at, id"
            ).fetchall()
            given = db.execute(
                "SELECT participant, trial, answer, ms, answered_at FROM answers ORDER BY participant, trial"
            ).fetchall()
        by_person: dict[str, list[tuple]] = {}
        for row in given:
            by_person.setdefault(row[0], []).append(row)
        answers = io.StringIO()
        out = csv.DictWriter(answers, ANSWER_COLUMNS, lineterminator="\n")
        out.writeheader()
        intro_ids = [q.id for q in self.study.questions]
        participants = io.StringIO()
        summary = csv.DictWriter(
            participants,
            ["participant", "started_at", "finished_at", "answered"]
            + [f"intro_{q}" for q in intro_ids]
            + ["passed_identical", "passed_mismatched"],
            lineterminator="\n",
            extrasaction="ignore",
        )
        summary.writeheader()
        for pid, plan, intro, started, finished in people:
            trials = [Trial.from_json(t) for t in json.loads(plan)]
            rows = by_person.get(pid, [])
            values = {trial: json.loads(answer) for _, trial, answer, _, _ in rows}
            for _, trial, _, ms, at in rows:
                out.writerows(_answer_rows(pid, trial, trials[trial], values[trial], ms, at))
            passed = check_results(trials, values)
            summary.writerow(
                {
                    "participant": pid,
                    "started_at": started,
                    "finished_at": finished or "",
                    "answered": len(rows),
                    **{f"intro_{k}": v for k, v in json.loads(intro).items()},
                    **{f"passed_{k}": "" if v is None else int(v) for k, v in passed.items()},
                }
            )
        return answers.getvalue(), participants.getvalue()


def _unfinished(participant: Participant) -> Participant:
    """``participant``, unless finished (409: one response set per participant)."""
    if participant.finished:
        raise StudyError("you have already taken part in this study: one response set per participant", 409)
    return participant


def _load(db: sqlite3.Connection, pid: str) -> Participant | None:
    """The participant with the stored id ``pid`` as ``db`` holds them, or None."""
    row = db.execute("SELECT plan, finished_at FROM participants WHERE id = ?", (pid,)).fetchone()
    if row is None:
        return None
    answered = db.execute("SELECT COUNT(*) FROM answers WHERE participant = ?", (pid,)).fetchone()[0]
    return Participant(pid, [Trial.from_json(t) for t in json.loads(row[0])], answered, row[1] is not None)


def _checked_answer(trial: Trial, answer: object) -> int | str | list[int]:
    """``answer`` if it answers ``trial`` (a rating 1-9 per face, or left/tie/right); else 422."""
    if trial.task == "pairwise":
        if answer not in PAIRWISE_ANSWERS:
            raise StudyError(f"a pairwise answer is one of: {', '.join(PAIRWISE_ANSWERS)}", 422)
        return str(answer)
    low, high = RATINGS[0], RATINGS[-1]
    if (
        not isinstance(answer, list)
        or len(answer) != len(trial.faces)
        or any(isinstance(a, bool) or a not in RATINGS for a in answer)
    ):
        raise StudyError(
            f"a rating answer is one whole number from {low} to {high} per face ({len(trial.faces)} here)", 422
        )
    return list(answer)


def _answer_rows(pid: str, number: int, trial: Trial, value: object, ms: int, at: str) -> list[dict]:
    common = {
        "participant": pid,
        "task": trial.task,
        "trial": number,
        "sentence": trial.sentence,
        "audio": trial.audio,
        "warmup": int(trial.warmup),
        "check": trial.check,
        "ms": ms,
        "answered_at": at,
        "expected": trial.expected,
    }
    if trial.task == "pairwise":
        return [{**common, "left": trial.faces[0].model, "right": trial.faces[1].model, "answer": value}]
    return [
        {**common, "position": k, "model": face.model, "answer": rating}
        for k, (face, rating) in enumerate(zip(trial.faces, _ratings(value)))
    ]


def _ratings(answer: object) -> list[int]:
    """A rating trial's stored ``answer``: one rating per face, as :func:`_checked_answer` let in."""
    return cast(list[int], answer)  # the trial's task, not the value's type, tells a rating answer


def check_results(trials: Sequence[Trial], answers: dict[int, object]) -> dict[str, bool | None]:
    """Whether a participant passed the ``identical`` and the ``mismatched`` checks (every one of
    that kind they answered), or None where they answered none. A rating identical check passes
    when the twin faces' ratings differ by one point at most; a rating mismatched check when its
    mean rating is below the participant's mean over the real items; a pairwise check when the
    answer is the expected one."""
    real = [
        r
        for k, t in enumerate(trials)
        if k in answers and t.task == "rating" and not t.check and not t.warmup
        for r in _ratings(answers[k])
    ]
    mean = sum(real) / len(real) if real else None
    results: dict[str, bool | None] = {"identical": None, "mismatched": None}
    for k, trial in enumerate(trials):
        if not trial.check or k not in answers:
            continue
        value = answers[k]
        if trial.task == "pairwise":
            ok = value == trial.expected
        elif trial.check == "identical":
            twins = [r for face, r in zip(trial.faces, _ratings(value)) if trial.faces.count(face) > 1]
            ok = max(twins) - min(twins) <= 1
        else:
            ratings = _ratings(value)
            ok = mean is not None and sum(ratings) / len(ratings) < mean
        results[trial.check] = ok if results[trial.check] is None else results[trial.check] and ok
    return results
