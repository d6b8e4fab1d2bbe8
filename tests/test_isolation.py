"""Chaos tests: native work crashing or hanging on purpose in its worker process
(vispeech.frontends.isolation's fault hook) costs that one request, line or message, nothing else."""

from __future__ import annotations

import contextlib
import faulthandler
import io
import json
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import require_module
from scipy.io import wavfile
from test_cli_say import assert_clean_error, run

from vispeech.batch import run_batch
from vispeech.batch.run import INDEX
from vispeech.errors import NativeFailure
from vispeech.frontends import isolation
from vispeech.frontends.audio import probe_upload
from vispeech.frontends.espeak import synthesize

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402

from vispeech.serve import ServeConfig, create_app  # noqa: E402

MARKER = "Chaosword"
"""Any text holding it crashes (or hangs) its worker, once the fault is set."""
KALAALLISUT = {"text": "1 2 3 4 5 6 7 8 9 10 100", "language": "kl"}
"""espeak-ng 1.52 (espeakng-loader 0.2.4) segfaults on this text in Greenlandic, in any process."""


@pytest.fixture
def crash(monkeypatch):
    monkeypatch.setenv(isolation.FAULT_VARIABLE, f"crash:{MARKER}")


@pytest.fixture
def hang(monkeypatch):
    monkeypatch.setenv(isolation.FAULT_VARIABLE, f"hang:{MARKER}")
    monkeypatch.setattr(isolation, "TIME_LIMIT", 1.0)


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    cache = tmp_path_factory.mktemp("chaos") / "cache.sqlite3"
    config = ServeConfig(cache=cache, rate_limit=0, default_model="baseline", stream_model="baseline", workers=2)
    with TestClient(create_app(config)) as client:
        yield client


def test_a_crash_is_that_call_s_error_and_the_next_call_runs(crash):
    with pytest.raises(NativeFailure, match="^espeak-ng crashed on this text in language en$"):
        synthesize(f"Say {MARKER} now.", "en")
    assert synthesize("Say hello now.", "en").duration > 0.3
    with pytest.raises(NativeFailure, match="^espeak-ng crashed on this text in language kl$"):
        synthesize(KALAALLISUT["text"], KALAALLISUT["language"])  # the real thing, no fault needed
    with pytest.raises(NativeFailure, match="^libsndfile crashed on the uploaded audio$"):
        probe_upload(f"RIFF {MARKER}".encode())


def test_a_worker_holds_none_of_the_caller_s_sockets(crash):
    with socket.socket() as listening:  # as a server's: a worker holding it would keep connections open
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        with pytest.raises(NativeFailure):
            synthesize(f"Say {MARKER} now.", "en")
        synthesize("Say hello now.", "en")  # by a worker forked while the socket was open
        held = f"socket:[{os.fstat(listening.fileno()).st_ino}]"
        workers = multiprocessing.active_children()
        assert workers
        # the worker forked in place of the crashed one may still be starting: it closes the socket then
        deadline = time.monotonic() + 10
        while any(held in open_files(w.pid) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not [w.pid for w in workers if held in open_files(w.pid)]


def test_a_worker_holds_none_of_the_caller_s_pipes(crash):
    """A program the caller feeds through a pipe (ffmpeg, Rscript, a library user's own) sees the end
    of its input when the caller closes it, though a native worker was forked while it was open."""
    reader = subprocess.Popen(["cat"], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    try:
        reader.stdin.write(b"some input")
        with pytest.raises(NativeFailure):
            synthesize(f"Say {MARKER} now.", "en")
        synthesize("Say hello now.", "en")  # by a worker forked while the pipe was open
        reader.stdin.close()
        assert reader.wait(timeout=10) == 0  # the worker forked in place of the crashed one may still be starting
    finally:
        reader.kill()
        reader.wait()


def test_ctrl_c_ends_the_server_and_its_workers_without_a_traceback(tmp_path):
    """Ctrl+C sends SIGINT to `vispeech serve` and to its native workers. The workers, forked from
    the event loop's process, inherited its signal wakeup fd (a socket they close): stopped, they
    printed two "Exception ignored when trying to write to the signal wakeup fd" tracebacks."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    log = tmp_path / "serve.log"
    with open(log, "wb") as out:
        server = subprocess.Popen(
            [sys.executable, "-c", "from vispeech.cli import main; main()", "serve", "--port", str(port),
             "--cache", ":memory:"],
            stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 60
            while True:
                assert server.poll() is None, log.read_text()
                with contextlib.suppress(OSError):
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/config", timeout=2):
                        break
                assert time.monotonic() < deadline, log.read_text()
                time.sleep(0.2)
            request = urllib.request.Request(
                f"http://127.0.0.1:{port}/api/speak", data=b'{"text": "Hello there.", "language": "en"}',
                headers={"Content-Type": "application/json"},
            )  # fmt: skip
            with urllib.request.urlopen(request, timeout=60) as answer:  # espeak-ng in the native workers
                assert answer.status == 200
            os.killpg(server.pid, signal.SIGINT)  # what a terminal's Ctrl+C does
            assert server.wait(30) == 0
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(server.pid, signal.SIGKILL)
            server.wait()
    output = log.read_text()
    assert "Finished server process" in output and "Traceback" not in output and "Exception" not in output, output


def open_files(pid: int) -> set[str]:
    """What process ``pid``'s file descriptors point at (none once it has ended)."""
    files = set()
    with contextlib.suppress(FileNotFoundError):
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(FileNotFoundError):  # closed meanwhile
                files.add(os.readlink(fd))
    return files


def test_a_hang_is_stopped_at_the_time_limit(hang):
    started = time.monotonic()
    with pytest.raises(NativeFailure, match="^espeak-ng took more than 1 s on this text in language en$"):
        synthesize(f"Say {MARKER} now.", "en")
    assert time.monotonic() - started < 10
    assert synthesize("Say hello now.", "en").duration > 0.3


def test_the_server_answers_a_crash_with_422_and_goes_on(client, crash):
    for body in ({"text": f"Hello {MARKER}.", "language": "en"}, KALAALLISUT):
        answer = client.post("/api/speak", json=body)
        assert answer.status_code == 422
        assert answer.json() == {"detail": f"espeak-ng crashed on this text in language {body['language']}"}
    assert client.get("/api/config").status_code == 200
    assert client.post("/api/speak", json={"text": "Hello there.", "language": "en"}).status_code == 200
    chat = client.post("/api/chat", json={"message": "Hello", "language": "en"}).json()
    assert chat["speech"]["audio_url"].endswith(".wav")


def test_an_upload_that_crashes_its_decoder_or_aligner_is_422(client, crash):
    buffer = io.BytesIO()
    wavfile.write(buffer, 16_000, np.zeros(1600, np.int16))
    answer = client.post(
        "/api/animate", content=buffer.getvalue() + MARKER.encode(), headers={"Content-Type": "audio/wav"}
    )
    assert answer.status_code == 422 and answer.json()["detail"] == "libsndfile crashed on the uploaded audio"
    answer = client.post(
        "/api/animate", params=KALAALLISUT, content=buffer.getvalue(), headers={"Content-Type": "audio/wav"}
    )
    assert answer.status_code == 422  # aligned against espeak-ng's speech of the text, which crashes
    assert answer.json()["detail"] == "espeak-ng crashed on this text in language kl"


def test_a_live_stream_gets_a_typed_error_and_goes_on(client, hang):
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": f"Hello. Then {MARKER} comes.", "language": "en"})
        messages = _until_end(ws)
        kinds = [m["type"] for m in messages]
        assert kinds[0] == "start" and "audio" in kinds  # the first clause went out
        assert messages[-1] == {"type": "error", "message": "espeak-ng took more than 1 s on this text in language en"}
        ws.send_json({"type": "text", "text": "Hello again.", "language": "en"})  # the same connection goes on
        assert _until_end(ws)[-1]["type"] == "end"
        ws.send_json({"type": "text", **KALAALLISUT})
        assert _until_end(ws) == [{"type": "error", "message": "espeak-ng crashed on this text in language kl"}]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_batch_writes_every_other_line(tmp_path, crash, workers):
    lines = [
        "id,text,language",
        "a,First line.,en",
        f"b,Then {MARKER}.,en",
        "c,1 2 3 4 5 6 7 8 9 10 100,kl",
        "d,Last.,en",
    ]
    (tmp_path / "job.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    report = run_batch(tmp_path / "job.csv", tmp_path / "out", workers=workers)
    assert [r.status for r in report.results] == ["written", "failed", "failed", "written"]
    assert report.results[1].error == "espeak-ng crashed on this text in language en"
    assert report.results[2].error == "espeak-ng crashed on this text in language kl"
    index = [json.loads(line) for line in (tmp_path / "out" / INDEX).read_text(encoding="utf-8").splitlines()]
    assert [entry["status"] for entry in index] == ["written", "failed", "failed", "written"]


def test_a_batch_line_whose_worker_process_dies_fails_alone(tmp_path, monkeypatch):
    import vispeech.batch.line as line_module

    prepare = line_module.prepare

    def dying(line):  # out of memory, say: the kernel kills the line's process
        if line.id == "b":
            os.kill(os.getpid(), signal.SIGKILL)
        return prepare(line)

    monkeypatch.setattr(line_module, "prepare", dying)  # the forked workers run it too
    rows = ["id,text,language", "a,First line.,en", "b,Second line.,en", "c,Third line.,en", "d,Last.,en"]
    (tmp_path / "job.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    report = run_batch(tmp_path / "job.csv", tmp_path / "out", workers=2)
    assert [r.status for r in report.results] == ["written", "failed", "written", "written"]
    assert report.results[1].error == "its worker process ended (exit code -9)"


def test_a_video_whose_capture_process_dies_fails_alone(tmp_path, monkeypatch):
    import vispeech.corpus.capture as capture

    def tracked(video, *args, **kwargs):  # MediaPipe or PyAV crashing on one video
        if video.stem == "b":
            faulthandler.disable()  # pytest's report of the crash would only be noise
            os.kill(os.getpid(), signal.SIGSEGV)

    monkeypatch.setattr(capture, "capture_take", tracked)  # the forked workers run these too
    monkeypatch.setattr(capture, "check_installed", lambda: None)
    monkeypatch.setattr(capture, "face_model_path", lambda path: path)
    for name in "abc":
        (tmp_path / f"{name}.mp4").write_bytes(b"")
    report = capture.capture_corpus(tmp_path, tmp_path / "out", jobs=2)
    assert report.captured == 2 and report.failed == [("b", "its worker process ended (exit code -11)")]


def test_a_cli_command_ends_with_one_line_and_exit_2(tmp_path, crash):
    result = run("say", f"Hello {MARKER}.", "-o", str(tmp_path / "out"))
    assert_clean_error(result)
    assert "espeak-ng crashed on this text in language en" in result.output
    assert not (tmp_path / "out").exists()


def _until_end(ws) -> list[dict]:
    messages = []
    while not messages or messages[-1]["type"] not in ("end", "error"):
        messages.append(ws.receive_json())
    return messages


def _spoken_length(text: str) -> int:
    """In a worker: samples espeak-ng speaks ``text`` in, through :func:`synthesize`'s own isolation."""
    return len(synthesize(text, "en").audio)
