"""The perceptual study: STUDY.toml, each participant's trials, the SQLite store, the web app,
and a scripted participant in headless Chromium (a server killed mid-study loses nothing)."""

from __future__ import annotations

import csv
import io
import json
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from conftest import copy_grid_utterances, require, require_module
from vispeech.errors import VispeechError
from vispeech.study.config import plan_trials, read_study
from vispeech.study.answers import ANSWER_COLUMNS
from vispeech.study.store import StudyError, StudyStore, check_results

COLOURS = {"red": (220, 30, 30), "blue": (30, 30, 220), "green": (30, 200, 30)}
"""Each model's face is a plain colour, so that the test can tell which model a slot shows."""

STUDY_TOML = """
title = "Faces test"
intro = "Judge the faces."
consent = "I agree."
seed = 7

[[questions]]
id = "experience"
text = "Experience with speech animation"
choices = ["None", "Small", "Moderate", "Expert"]

[[clips]]
sentence = "s0"
path = "clips/s0.mp4"
models = ["red", "blue", "green"]

[[clips]]
sentence = "s1"
path = "clips/s1.mp4"

[[clips]]
sentence = "s2"
path = "clips/s2.mp4"
models = ["red", "blue", "green"]

[rating]
anchors = { 1 = "Not realistic at all", 9 = "Completely realistic" }
warmup = 1

[pairwise]
pairs = [["red", "blue"], ["red", "green"]]
warmup = 1
"""


def make_clip(path: Path, models: list[str], seconds: float = 0.6, size: int = 48) -> None:
    """A composite clip: one plain-coloured column per model, a tone as its sound (H.264 + AAC)."""
    av = require_module("av", "PyAV (the capture extra)")
    frame = np.concatenate([np.broadcast_to(np.array(COLOURS[m], np.uint8), (size, size, 3)) for m in models], axis=1)
    rate = 16000
    with av.open(str(path), "w", format="mp4") as container:
        video = container.add_stream("libx264", rate=Fraction(25))
        video.width, video.height, video.pix_fmt = frame.shape[1], size, "yuv420p"
        sound = container.add_stream("aac", rate=rate, layout="mono")
        for _ in range(int(seconds * 25)):
            container.mux(video.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")))
        container.mux(video.encode())
        pcm = (np.sin(np.arange(int(seconds * rate)) * 2 * np.pi * 220 / rate) * 8000).astype(np.int16)
        for begin in range(0, len(pcm), 1024):
            chunk = av.AudioFrame.from_ndarray(pcm[None, begin:begin + 1024], format="s16", layout="mono")
            chunk.sample_rate = rate
            container.mux(sound.encode(chunk))
        container.mux(sound.encode())


@pytest.fixture
def study_file(tmp_path: Path) -> Path:
    """A study of three sentences and three models; s1's models come from its stimuli key."""
    (tmp_path / "clips").mkdir()
    for sentence in ("s0", "s1", "s2"):
        make_clip(tmp_path / "clips" / f"{sentence}.mp4", ["red", "blue", "green"])
    (tmp_path / "clips" / "s1.json").write_text(json.dumps(
        {"clip": "s1.mp4", "left_to_right": ["anims/red.json", "anims/blue.json", "anims/green.json"]}))
    path = tmp_path / "study.toml"
    path.write_text(STUDY_TOML, encoding="utf-8")
    return path


# --- STUDY.toml -------------------------------------------------------------------------------

def test_a_study_reads_its_clips_and_takes_models_from_the_stimuli_key(study_file):
    study = read_study(study_file)
    assert [c.sentence for c in study.clips] == ["s0", "s1", "s2"]
    assert study.clips[1].models == ["red", "blue", "green"]
    assert study.clips[0].path == (study_file.parent / "clips" / "s0.mp4").resolve()
    assert study.rating.anchors == {1: "Not realistic at all", 9: "Completely realistic"}
    # clips of `vispeech animate` folders: every animation is an animation.json, named by its folder
    (study_file.parent / "clips" / "s1.json").write_text(json.dumps({"clip": "s1.mp4", "left_to_right": [
        "/takes/red/animation.json", "/takes/blue/animation.json", "/takes/green/animation.json"]}))
    assert read_study(study_file).clips[1].models == ["red", "blue", "green"]


@pytest.mark.parametrize("change, message", [
    (lambda s: s.replace('path = "clips/s2.mp4"', 'path = "clips/none.mp4"'), "none.mp4 not found"),
    (lambda s: s.replace('path = "clips/s2.mp4"', 'path = "study.toml"'), "study.toml is not an MP4 file"),
    (lambda s: s.replace('["red", "green"]]', '["red", "violet"]]'), "names models no clip shows: violet"),
    (lambda s: s.replace("[rating]", "[ratings]"), "ratings: Extra inputs are not permitted"),
    (lambda s: s.replace("1 = ", "10 = "), "anchors are keyed by ratings 1 to 9"),
    (lambda s: s.replace('title = "Faces test"', 'title = "Faces'), "is not valid TOML"),
    (lambda s: s.split("[rating]")[0], "a study needs a [rating] or a [pairwise] task"),
    (lambda s: s.replace('sentence = "s2"', 'sentence = "s0"'), "each clip must have its own sentence"),
    # files that read, then broke every participant's join (a 500 each)
    (lambda s: s.replace("warmup = 1\n\n[pairwise]", 'warmup = 1\nmodels = ["red"]\n\n[pairwise]'),
     "rating.models: List should have at least 2 items"),
    (lambda s: s.replace("warmup = 1\n\n[pairwise]", 'warmup = 1\nmodels = []\n\n[pairwise]'),
     "rating.models: List should have at least 2 items"),
    (lambda s: s.replace("seed = 7", "seed = -1"), "seed: Input should be greater than or equal to 0"),
    (lambda s: s.replace("seed = 7", "seed = 9223372036854775807"), "seed: Input should be less than or equal to"),
])
def test_a_bad_study_is_refused_in_one_line(study_file, change, message):
    study_file.write_text(change(STUDY_TOML), encoding="utf-8")
    with pytest.raises(VispeechError, match=message.replace("[", r"\[").replace("]", r"\]")) as caught:
        read_study(study_file)
    assert "\n" not in str(caught.value) and "Value error" not in str(caught.value)  # as study.md shows them


# --- each participant's trials ----------------------------------------------------------------

def test_trials_follow_the_thesis_design(study_file):
    study = read_study(study_file)
    trials = plan_trials(study, seed=3)
    assert trials == plan_trials(study, seed=3)
    assert trials != plan_trials(study, seed=4)
    rating = [t for t in trials if t.task == "rating"]
    pairwise = [t for t in trials if t.task == "pairwise"]
    assert trials == rating + pairwise
    # every clip once as a real rating item, plus the warm-up's copy and two checks
    real = [t for t in rating if not t.warmup and not t.check]
    assert Counter(t.sentence for t in real) == {"s0": 1, "s1": 1, "s2": 1}
    assert len(rating) == 3 + 1 + 2
    assert rating[0].warmup and not any(t.warmup for t in rating[1:])
    assert {f.model for f in rating[-1].faces} == {f.model for f in rating[0].faces}
    assert rating[-1].sentence == rating[0].sentence
    checks = {t.check: t for t in rating if t.check}
    assert set(checks) == {"identical", "mismatched"}
    identical = checks["identical"]
    assert len(set(identical.faces)) == len(identical.faces) - 1 and identical.expected == "alike"
    mismatched = checks["mismatched"]
    assert mismatched.audio != mismatched.sentence and mismatched.expected == "lower"
    # pairwise: each clip x each pair once, one warm-up copy, two checks
    real = [t for t in pairwise if not t.warmup and not t.check]
    assert len(pairwise) == 6 + 1 + 2 and len(real) == 6
    shown = Counter((t.sentence, frozenset(f.model for f in t.faces)) for t in pairwise[1:] if not t.check)
    assert all(shown[(s, frozenset(p))] == 1 for s in ("s0", "s1", "s2") for p in (("red", "blue"), ("red", "green")))
    checks = {t.check: t for t in pairwise if t.check}
    assert checks["identical"].faces[0] == checks["identical"].faces[1] and checks["identical"].expected == "tie"
    odd = checks["mismatched"]
    assert odd.faces[0].model == odd.faces[1].model and odd.faces[0].sentence != odd.faces[1].sentence
    assert odd.expected == ("left" if odd.faces[0].sentence == odd.audio else "right")


def test_positions_are_randomised_over_participants(study_file):
    study = read_study(study_file)
    slots = Counter()
    for seed in range(60):
        for trial in plan_trials(study, seed):
            if trial.task == "rating" and not trial.check:
                slots.update((k, f.model) for k, f in enumerate(trial.faces))
    counts = np.array([[slots[(k, m)] for m in COLOURS] for k in range(3)])
    assert counts.min() > 0.6 * counts.mean()  # every model in every position, roughly evenly


# --- the store --------------------------------------------------------------------------------

def _rating_for(trial) -> list[int]:
    return [{"red": 8, "blue": 3, "green": 5}[f.model] for f in trial.faces]


def _pairwise_for(trial) -> str:
    left, right = (f.model for f in trial.faces)
    return "tie" if left == right else "left" if left == "red" else "right" if right == "red" else "tie"


def test_answers_are_kept_in_order_and_once(study_file, tmp_path):
    study = read_study(study_file)
    store = StudyStore(tmp_path / "answers.sqlite3", study)
    who = store.join("pid:abc", {"experience": "Small"})
    assert who.answered == 0 and not who.finished and who.id != "abc"
    trials = who.trials
    with pytest.raises(StudyError, match="trial 1 is not the next one") as caught:
        store.answer(who.id, 1, "left", 100)
    assert caught.value.status == 409
    first = _rating_for(trials[0])
    with pytest.raises(StudyError, match="one whole number from 1 to 9 per face"):
        store.answer(who.id, 0, first[:-1], 100)
    with pytest.raises(StudyError, match="one whole number from 1 to 9"):
        store.answer(who.id, 0, [0] * len(first), 100)
    store.answer(who.id, 0, first, 1200)
    with pytest.raises(StudyError, match="trial 1 is"):
        store.answer(who.id, 0, first, 1200)
    # a second store on the same file (a restarted server) sees the answer and the same trials
    again = StudyStore(tmp_path / "answers.sqlite3", study)
    back = again.join("pid:abc", {"experience": "Small"})
    assert back.answered == 1 and back.trials == trials
    for k, trial in enumerate(trials[1:], start=1):
        answer = _rating_for(trial) if trial.task == "rating" else _pairwise_for(trial)
        assert again.answer(who.id, k, answer, 900 + k).answered == k + 1
    assert again.participant(who.id).finished
    with pytest.raises(StudyError, match="every trial is already answered") as caught:  # past the last
        again.answer(who.id, len(trials), _rating_for(trials[0]), 10)
    assert caught.value.status == 409
    with pytest.raises(StudyError, match="already taken part") as caught:
        again.join("pid:abc", {"experience": "Small"})
    assert caught.value.status == 409
    with pytest.raises(StudyError, match="intro question 'experience' needs one of"):
        again.join("pid:other", {"experience": "Lots"})


def test_a_changed_study_is_refused_once_anyone_joined(study_file, tmp_path):
    """Edited before anyone joins: taken. Its clips or models changed after: refused in one line
    (the stored participants' trials would name what is gone); its texts changed: taken."""
    import sqlite3

    db = tmp_path / "answers.sqlite3"
    StudyStore(db, read_study(study_file))

    def design() -> str:
        with sqlite3.connect(db) as connection:
            return connection.execute("SELECT value FROM meta WHERE key = 'design'").fetchone()[0]

    first = design()
    study_file.write_text(STUDY_TOML.replace("seed = 7", "seed = 8"), encoding="utf-8")
    StudyStore(db, read_study(study_file), create=False)  # an export reads; it records nothing
    assert design() == first
    study_file.write_text(STUDY_TOML.replace('models = ["red", "blue", "green"]\n\n[[clips]]\nsentence = "s1"',
                                             'models = ["blue", "red", "green"]\n\n[[clips]]\nsentence = "s1"'),
                          encoding="utf-8")
    StudyStore(db, read_study(study_file)).join("pid:a", {"experience": "None"})
    study_file.write_text(STUDY_TOML, encoding="utf-8")  # the models' order as first written: other answers
    with pytest.raises(VispeechError, match="holds the answers of 1 participant of another version") as caught:
        StudyStore(db, read_study(study_file))
    assert "\n" not in str(caught.value)
    study_file.write_text(STUDY_TOML.replace('models = ["red", "blue", "green"]\n\n[[clips]]\nsentence = "s1"',
                                             'models = ["blue", "red", "green"]\n\n[[clips]]\nsentence = "s1"')
                          .replace('title = "Faces test"', 'title = "Faces, again"'), encoding="utf-8")
    assert StudyStore(db, read_study(study_file)).join("pid:a", {"experience": "None"}).answered == 0


def test_the_export_holds_every_answer_as_given(study_file, tmp_path):
    study = read_study(study_file)
    store = StudyStore(tmp_path / "answers.sqlite3", study)
    given = {}
    for name in ("p1", "p2"):
        who = store.join(f"pid:{name}", {"experience": "None"})
        for k, trial in enumerate(who.trials[:10 if name == "p2" else None]):
            answer = _rating_for(trial) if trial.task == "rating" else _pairwise_for(trial)
            store.answer(who.id, k, answer, 1000 + k)
            given[(who.id, k)] = (trial, answer)
    answers, participants = store.export()
    rows = list(csv.DictReader(io.StringIO(answers)))
    assert tuple(rows[0]) == ANSWER_COLUMNS
    seen = Counter()
    for row in rows:
        trial, answer = given[(row["participant"], int(row["trial"]))]
        seen[(row["participant"], int(row["trial"]))] += 1
        assert row["task"] == trial.task and int(row["warmup"]) == trial.warmup and row["check"] == trial.check
        assert row["sentence"] == trial.sentence and row["audio"] == trial.audio
        assert int(row["ms"]) == 1000 + int(row["trial"])
        if trial.task == "rating":
            k = int(row["position"])
            assert row["model"] == trial.faces[k].model and int(row["answer"]) == answer[k]
        else:
            assert (row["left"], row["right"]) == (trial.faces[0].model, trial.faces[1].model)
            assert row["answer"] == answer
    assert set(seen) == set(given)
    people = {row["participant"]: row for row in csv.DictReader(io.StringIO(participants))}
    assert len(people) == 2 and all(p["intro_experience"] == "None" for p in people.values())
    assert sorted(int(p["answered"]) for p in people.values()) == [10, len(plan_trials(study, 0))]
    finished = [p for p in people.values() if p["finished_at"]]
    assert len(finished) == 1
    # the scripted answers rate twins alike (pass) and rate a mismatched clip as any other (fail)
    assert finished[0]["passed_identical"] == "1" and finished[0]["passed_mismatched"] == "0"


def test_check_results(study_file):
    trials = plan_trials(read_study(study_file), 0)
    answers = {k: (_rating_for(t) if t.task == "rating" else _pairwise_for(t)) for k, t in enumerate(trials)}
    for k, trial in enumerate(trials):
        if trial.check == "mismatched":
            answers[k] = [1] * len(trial.faces) if trial.task == "rating" else trial.expected
    assert check_results(trials, answers) == {"identical": True, "mismatched": True}
    twin = next(k for k, t in enumerate(trials) if t.task == "rating" and t.check == "identical")
    faces = trials[twin].faces
    first = faces.index(next(f for f in faces if faces.count(f) > 1))
    answers[twin] = [9 if i == first else 1 for i in range(len(faces))]
    assert check_results(trials, answers)["identical"] is False
    assert check_results(trials, {}) == {"identical": None, "mismatched": None}


# --- the web app (in process) -----------------------------------------------------------------

@pytest.fixture
def client(study_file, tmp_path):
    testclient = require_module("fastapi.testclient", "FastAPI (the serve extra)")
    from vispeech.study.app import create_app

    study = read_study(study_file)
    app = create_app(study, StudyStore(tmp_path / "answers.sqlite3", study), admin_token="sesame")
    with testclient.TestClient(app) as client:
        yield client


def test_the_app_takes_a_participant_through_without_telling_the_models(client):
    assert client.get("/api/me").status_code == 404
    page = client.get("/")
    assert page.status_code == 200 and "study.js" in page.text
    info = client.get("/api/study").json()
    assert info["title"] == "Faces test"
    assert info["anchors"] == {"1": "Not realistic at all", "9": "Completely realistic"}
    refused = client.post("/api/join", json={"consent": False, "intro": {"experience": "None"}})
    assert refused.status_code == 400 and "consent" in refused.json()["detail"]
    assert client.post("/api/join", json={"consent": True, "intro": {}}).status_code == 422
    assert client.post("/api/join", json={"consent": "yes", "intro": {"experience": "None"}}).status_code == 422
    progress = client.post("/api/join", json={"consent": True, "intro": {"experience": "Expert"}}).json()
    assert progress["next"] == 0 and len(progress["trials"]) == 15
    text = json.dumps(progress)
    assert not any(model in text for model in COLOURS)  # the page never learns which model is where
    face = progress["trials"][0]["faces"][0]
    assert face["clip"].startswith("/clips/s") and face["columns"] == 3
    clip = client.get(face["clip"])
    assert clip.status_code == 200 and clip.headers["content-type"] == "video/mp4"
    assert client.get("/clips/s9.mp4").status_code == 404
    bad = client.post("/api/answers", json={"trial": 0, "answer": "LEFT", "ms": 10})
    assert bad.status_code == 422 and bad.json()["detail"] == (
        "answer: a rating trial's is a list of whole numbers, a pairwise trial's 'left', 'tie' or 'right'")
    wrong = client.post("/api/answers", json={"trial": 0, "answer": [5], "ms": 10})
    assert wrong.status_code == 422 and "per face" in wrong.json()["detail"]
    width = len(progress["trials"][0]["faces"])
    for loose in ({"trial": 0, "answer": [True] * width, "ms": 10}, {"trial": 0, "answer": ["5"] * width, "ms": 10},
                  {"trial": True, "answer": [5] * width, "ms": 10}):  # nothing taken for what it is not
        assert client.post("/api/answers", json=loose).status_code == 422, loose
    for k, trial in enumerate(progress["trials"]):
        answer = [5] * len(trial["faces"]) if trial["task"] == "rating" else "tie"
        reply = client.post("/api/answers", json={"trial": k, "answer": answer, "ms": 10})
        assert reply.status_code == 200 and reply.json()["next"] == k + 1
    assert client.get("/api/me").json()["finished"]
    again = client.post("/api/join", json={"consent": True, "intro": {"experience": "Expert"}})
    assert again.status_code == 409 and "already taken part" in again.json()["detail"]


def test_a_shared_browser_never_continues_another_participants_answers(client):
    """P1 answers in a browser; P2's link opened in the same browser (P1's cookie still in it) is
    a new participant, not P1's next trial; P1's link there still finds P1."""
    first = client.post("/api/join", json={"consent": True, "pid": "P1", "intro": {"experience": "None"}}).json()
    answer = [5] * len(first["trials"][0]["faces"]) if first["trials"][0]["task"] == "rating" else "tie"
    assert client.post("/api/answers", json={"trial": 0, "answer": answer, "ms": 10}).json()["next"] == 1
    assert client.get("/api/me", params={"pid": "P1"}).json()["next"] == 1
    assert client.get("/api/me").json()["next"] == 1  # a link without a pid: the browser's participant
    other = client.get("/api/me", params={"pid": "P2"})
    assert other.status_code == 404  # the page asks P2 to join
    second = client.post("/api/join", json={"consent": True, "pid": "P2", "intro": {"experience": "None"}})
    assert second.json()["next"] == 0
    assert client.get("/api/me", params={"pid": "P1"}).status_code == 404  # the cookie is P2's now


def test_the_page_speaks_the_study_s_language(study_file, tmp_path):
    testclient = require_module("fastapi.testclient", "FastAPI (the serve extra)")
    from vispeech.study.app import create_app

    study_file.write_text(STUDY_TOML + '\n[labels]\nplay = "Spela"\nitem = "Fråga {n} av {total}"\n', encoding="utf-8")
    study = read_study(study_file)
    with testclient.TestClient(create_app(study, StudyStore(tmp_path / "a.sqlite3", study), "x")) as client:
        labels = client.get("/api/study").json()["labels"]
    assert labels["play"] == "Spela" and labels["item"] == "Fråga {n} av {total}" and labels["next"] == "Next"
    study_file.write_text(STUDY_TOML + '\n[labels]\nplai = "Spela"\n', encoding="utf-8")
    with pytest.raises(VispeechError, match="labels.plai: Extra inputs are not permitted"):
        read_study(study_file)


def test_the_export_needs_the_admin_token(client):
    assert client.get("/admin/answers.csv").status_code == 401
    assert client.get("/admin/answers.csv", headers={"Authorization": "Bearer nope"}).status_code == 403
    reply = client.get("/admin/answers.csv", headers={"Authorization": "Bearer sesame"})
    assert reply.status_code == 200 and reply.text.startswith(",".join(ANSWER_COLUMNS))
    assert client.get("/admin/participants.csv?token=sesame").text.startswith("participant,")


# --- a scripted participant in headless Chromium ----------------------------------------------

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TOKEN = "let-me-in"


def _start_server(study: Path, port: int, log: Path) -> subprocess.Popen:
    """`vispeech study serve STUDY` on 127.0.0.1:``port``, answering."""
    httpx = require_module("httpx", "httpx (the test extra)")
    command = shutil.which("vispeech", path=str(Path(sys.executable).parent)) or "vispeech"
    process = subprocess.Popen([command, "study", "serve", str(study), "--port", str(port), "--admin-token", TOKEN],
                               stdout=log.open("ab"), stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/study", timeout=2).status_code == 200:
                return process
        except httpx.TransportError:
            pass
        assert process.poll() is None, f"the study server stopped: {log.read_text()[-2000:]}"
        assert time.monotonic() < deadline, "the study server did not start in 60 s"
        time.sleep(0.2)


def _slot_models(page) -> list[str]:
    """The model each canvas shows, told by its colour."""
    pixels = page.evaluate("""() => [...document.querySelectorAll('#faces canvas')].map((c) =>
        [...c.getContext('2d').getImageData(c.width >> 1, c.height >> 1, 1, 1).data.slice(0, 3)])""")
    return [min(COLOURS, key=lambda m: sum((a - b) ** 2 for a, b in zip(COLOURS[m], rgb))) for rgb in pixels]


def _answer_trials(page, clicked: dict[int, tuple[list[str], object]], stop_after: int | None = None) -> None:
    """Answer as a participant who likes red (8), then green (5), then blue (3), and prefers red in a
    pair; until the thanks page, or until ``stop_after`` answers in all have been committed."""
    while stop_after is None or len(clicked) < stop_after:
        page.wait_for_selector("#trial:not([hidden]), #done:not([hidden])")
        if page.is_visible("#done"):
            return
        number = int(page.text_content("#count").split()[1]) - 1
        page.click("#play")
        page.wait_for_selector("#choices:not([hidden]), #ratings:not([hidden])", timeout=20_000)
        models = _slot_models(page)
        if page.is_visible("#choices"):
            left, right = models
            answer = "tie" if left == right else "left" if left == "red" else "right" if right == "red" else "tie"
            page.click(f"#choose-{answer}")
        else:
            answer = [{"red": 8, "green": 5, "blue": 3}[m] for m in models]
            for slot, value in zip("ABCDEFGHIJ", answer):
                page.check(f"#rate-{slot}-{value}")
            page.click("#next")
        page.wait_for_function("(shown) => !document.querySelector('#done').hidden || "
                               "document.querySelector('#count').textContent !== shown",
                               arg=f"Item {number + 1} of 15")
        clicked[number] = (models, answer)


@pytest.mark.browser
def test_a_participant_completes_the_study_in_chromium_and_a_killed_server_loses_nothing(study_file, tmp_path):
    require(CHROMIUM.is_file(), f"Chromium ({CHROMIUM}: apt-get install chromium)")
    sync_api = require_module("playwright.sync_api", "Playwright (the test extra)")
    httpx = require_module("httpx", "httpx (the test extra)")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    log = tmp_path / "server.log"
    base = f"http://127.0.0.1:{port}"
    clicked: dict[int, tuple[list[str], object]] = {}
    server = _start_server(study_file, port, log)
    try:
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS)
            try:
                page = browser.new_page()
                errors = []
                page.on("pageerror", lambda error: errors.append(str(error)))
                page.goto(f"{base}/?pid=tester-1")
                page.wait_for_selector("#welcome:not([hidden])")
                assert page.text_content("#title") == "Faces test"
                page.click("#start")  # no consent, no intro answers: the browser's form refuses
                assert page.is_visible("#welcome")
                page.check("#q-experience-2")
                page.check("#consent")
                page.click("#start")
                _answer_trials(page, clicked, stop_after=6)
                server.send_signal(signal.SIGKILL)
                server.wait(10)
                # every acknowledged answer is on disk, read by a fresh store
                study = read_study(study_file)
                saved = StudyStore(study_file.with_suffix(".sqlite3"), study)
                answers, _ = saved.export()
                assert sorted({int(r["trial"]) for r in csv.DictReader(io.StringIO(answers))}) == list(range(6))
                server = _start_server(study_file, port, log)
                page.reload()
                page.wait_for_selector("#trial:not([hidden])")
                assert page.text_content("#count") == "Item 7 of 15"
                _answer_trials(page, clicked)
                assert page.is_visible("#done") and page.text_content("#thanks") == "Thank you for taking part."
                assert errors == []
            finally:
                browser.close()
        assert sorted(clicked) == list(range(15))
        export = httpx.get(f"{base}/admin/answers.csv", headers={"Authorization": f"Bearer {TOKEN}"})
        people = httpx.get(f"{base}/admin/participants.csv", params={"token": TOKEN})
    finally:
        server.terminate()
        server.wait(10)
    rows = list(csv.DictReader(io.StringIO(export.text)))
    for row in rows:
        models, answer = clicked[int(row["trial"])]
        if row["task"] == "rating":
            k = int(row["position"])
            assert row["model"] == models[k] and int(row["answer"]) == answer[k]
        else:
            assert [row["left"], row["right"]] == models and row["answer"] == answer
        assert 0 < int(row["ms"]) < 120_000
    participants = list(csv.DictReader(io.StringIO(people.text)))
    assert len(participants) == 1 and participants[0]["finished_at"]
    assert participants[0]["intro_experience"] == "Moderate"
    assert participants[0]["passed_identical"] == "1"
    # the analysis counts the wins, ties and losses that were clicked (warm-ups and checks left out)
    require(shutil.which("Rscript"), "R (apt-get install r-base-core r-cran-ordinal r-cran-car r-cran-emmeans "
                                     "r-cran-jsonlite)")
    from vispeech.study.analysis import ALL_SENTENCES, analyse_answers, read_answers, read_participants

    (tmp_path / "answers.csv").write_text(export.text, encoding="utf-8")
    (tmp_path / "participants.csv").write_text(people.text, encoding="utf-8")
    analysis = analyse_answers(read_answers(tmp_path / "answers.csv"),
                               participants=read_participants(tmp_path / "participants.csv"), random_slopes=False)
    real = {int(r["trial"]) for r in rows if r["warmup"] == "0" and not r["check"]}
    for task, table in (("rating", analysis.tasks["rating"].wins), ("pairwise", analysis.tasks["pairwise"].wins)):
        expected = Counter()
        for number in real:
            models, answer = clicked[number]
            if task == "rating" and isinstance(answer, list):
                scores = dict(zip(models, answer))
            elif task == "pairwise" and isinstance(answer, str):
                scores = dict(zip(models, {"left": (2, 0), "tie": (1, 1), "right": (0, 2)}[answer]))
            else:
                continue
            for a in scores:
                for b in scores:
                    if a < b:
                        expected[(a, b)] += np.array([scores[a] > scores[b], scores[a] == scores[b],
                                                      scores[a] < scores[b]], int)
        total = table[table["sentence"] == ALL_SENTENCES]
        found = {(r.a, r.b): [r.a_wins, r.ties, r.b_wins] for r in total.itertuples() if r.a_wins + r.ties + r.b_wins}
        assert found == {pair: list(counts) for pair, counts in expected.items()}, task


# --- the command line -------------------------------------------------------------------------

def _cli(*args):
    from click.testing import CliRunner

    from vispeech.cli import main

    return CliRunner().invoke(main, ["study", *map(str, args)])


def test_study_export_writes_the_answers_and_refuses_bad_input_in_one_line(study_file, tmp_path):
    study = read_study(study_file)
    store = StudyStore(study_file.with_suffix(".sqlite3"), study)
    who = store.join("pid:one", {"experience": "None"})
    store.answer(who.id, 0, _rating_for(who.trials[0]), 500)
    result = _cli("export", study_file, "-o", tmp_path / "out")
    assert result.exit_code == 0, result.output
    assert "3 answer rows, 1 participants" in result.output
    rows = list(csv.DictReader((tmp_path / "out" / "answers.csv").open(encoding="utf-8")))
    assert [int(r["answer"]) for r in rows] == _rating_for(who.trials[0])
    assert (tmp_path / "out" / "participants.csv").is_file()
    missing = _cli("export", study_file, "--db", tmp_path / "none.sqlite3", "-o", tmp_path / "out2")
    assert missing.exit_code == 2 and "none.sqlite3 not found" in missing.output
    assert len(missing.output.splitlines()) == 1 and not (tmp_path / "out2").exists()
    for other in (b"", None):  # an empty file; another program's SQLite database: neither is made a study's
        path = tmp_path / "other.sqlite3"
        if other is None:
            import sqlite3

            path.unlink()
            with sqlite3.connect(path) as db:
                db.execute("CREATE TABLE notes (text TEXT)")
        else:
            path.write_bytes(other)
        before = path.read_bytes()
        result = _cli("export", study_file, "--db", path, "-o", tmp_path / "out4")
        assert result.exit_code == 2 and "is not a study database (it has no study's answers)" in result.output
        assert path.read_bytes() == before and not (tmp_path / "out4").exists()
    (tmp_path / "junk.sqlite3").write_bytes(b"not a database at all, just bytes" * 40)
    junk = _cli("export", study_file, "--db", tmp_path / "junk.sqlite3", "-o", tmp_path / "out3")
    assert junk.exit_code == 2 and "is not a study database" in junk.output and len(junk.output.splitlines()) == 1
    study_file.write_text(STUDY_TOML.replace("[rating]", "[ratin]"), encoding="utf-8")
    bad = _cli("serve", study_file)
    assert bad.exit_code == 2 and bad.output.startswith("error:") and len(bad.output.splitlines()) == 1


# --- a study made from a recorded corpus ------------------------------------------------------

@pytest.mark.browser
def test_study_prepare_renders_the_recording_and_the_models_into_a_study_that_runs(grid_s1, tmp_path):
    require(CHROMIUM.is_file(), f"Chromium ({CHROMIUM}: apt-get install chromium)")
    require_module("playwright.sync_api", "Playwright (the test extra)")
    av = require_module("av", "PyAV (the capture extra)")
    from vispeech.corpus.corpus import split_of

    root = copy_grid_utterances(grid_s1, tmp_path / "corpus", 2)
    texts = dict(line.split("\t") for line in (root / "sentences.tsv").read_text().splitlines()[1:])
    ids = sorted(texts)
    split = split_of(ids[0])
    result = _cli("prepare", "--corpus", root, "--split", split, "-m", "recorded", "-m", "baseline",
                  "--sentences", "1", "--cache", tmp_path / "cache", "-q", "-o", tmp_path / "study")
    assert result.exit_code == 0, result.output
    study = read_study(tmp_path / "study" / "study.toml")
    assert len(study.clips) == 1 and study.clips[0].models == ["recorded", "baseline"]
    clip = study.clips[0]
    assert clip.sentence in ids and clip.text == texts[clip.sentence]
    with av.open(str(clip.path)) as container:
        sound = container.streams.audio[0]
        duration = float(sound.duration * sound.time_base)
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    with av.open(str(grid_s1 / "utterances" / f"{clip.sentence}.flac")) as source:
        assert abs(duration - source.duration / 1e6) < 0.1
    assert frames[0].shape[1] == 2 * frames[0].shape[0] * 4 // 5  # two 4:5 faces side by side
    # the two faces move differently (the recording is not the rule baseline)
    half = frames[0].shape[1] // 2
    motion = np.array([np.abs(f[:, :half].astype(int) - f[:, half:].astype(int)).mean() for f in frames])
    assert motion.max() > 1.0
    assert {t.task for t in plan_trials(study, 0)} == {"rating", "pairwise"}
    again = _cli("prepare", "--corpus", root, "-m", "recorded", "-m", "recorded", "-o", tmp_path / "other")
    assert again.exit_code == 2 and "each --model once" in again.output and not (tmp_path / "other").exists()


def test_the_study_server_has_the_guards_of_serve(study_file, tmp_path):
    testclient = require_module("fastapi.testclient", "FastAPI (the serve extra)")
    from vispeech.guards import TokenBucket
    from vispeech.study.app import create_app

    study = read_study(study_file)
    app = create_app(study, StudyStore(tmp_path / "a.sqlite3", study), "x", max_body_bytes=1000,
                     joins=TokenBucket(0.001, 3))
    joining = {"consent": True, "intro": {"experience": "Expert"}}
    with testclient.TestClient(app) as client:
        assert client.get("/api/study", headers={"host": "rebind.attacker.example"}).status_code == 400
        foreign = client.post("/api/join", json=joining, headers={"origin": "https://attacker.example"})
        assert foreign.status_code == 403 and "Origin" in foreign.json()["detail"]
        declared = client.post("/api/join", content=b"{" + b" " * 5000 + b"}",
                               headers={"content-type": "application/json"})
        assert declared.status_code == 413 and "too large" in declared.json()["detail"]
        streamed = client.post("/api/join", content=iter([b"{" + b" " * 600, b" " * 600 + b"}"]),
                               headers={"content-type": "application/json"})  # chunked: no Content-Length
        assert streamed.status_code == 413
        for n in range(3):
            assert client.post("/api/join", json={**joining, "pid": f"p{n}"}).status_code == 200
        refused = client.post("/api/join", json={**joining, "pid": "p3"})
        assert refused.status_code == 429 and "too many joins" in refused.json()["detail"]
        assert client.get("/api/me").status_code == 200  # only joining is limited
