"""Issue 24's crashing request through every route, and a batch holding it: nothing else may fail.

    python benchmarks/crash_server.py [--times 100] [--batch 200] [--json OUT]

espeak-ng segfaults on ``{"text": "1 2 3 4 5 6 7 8 9 10 100", "language": "kl"}``. This starts
`vispeech serve` on a free loopback port (no rate limit, a temporary cache, chat relayed to
an echo service in this process, so the reply is the message) and sends that request
``--times`` times through each route: ``POST /api/speak``, a text on ``/api/stream`` (a new
connection each time, a good text after it on the same connection), ``POST /api/animate?text=...`` (a WAV of speech as the body) and
``POST /api/chat``, each followed by a good ``/api/speak`` (a new text, so it is computed),
while another thread asks ``GET /api/config`` every 50 ms. Then ``vispeech batch`` runs the
line plus ``--batch - 1`` good ones, with the default jobs and with ``--jobs 1``.

It fails (exit 1) when a crashing request gets anything but one error (a 4xx with a message,
or one stream ``error``), a good request or ``/api/config`` fails, the p95 of ``/api/config``
exceeds 200 ms, the server dies, or a batch does not write every good line, list the bad one as
failed in ``index.jsonl`` and exit 1.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import httpx
from local_server import running_server
from websockets.sync.client import connect

KL = {"text": "1 2 3 4 5 6 7 8 9 10 100", "language": "kl"}


class _Echo(BaseHTTPRequestHandler):
    def do_POST(self) -> None:  # noqa: N802 (http.server's name)
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))  # an OpenAI-shaped chat service
        answer = json.dumps({"choices": [{"message": {"content": body["messages"][-1]["content"]}}]}).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(answer)))
        self.end_headers()
        self.wfile.write(answer)

    def log_message(self, *args) -> None:
        pass


def _crash(route: str, client: httpx.Client, url: str, wav: bytes) -> str:
    """One crashing request through ``route``: what came back, as ``"<status>: <message>"``."""
    if route == "stream":
        with connect(url.replace("http://", "ws://") + "/api/stream") as ws:
            ws.send(json.dumps({"type": "text", **KL}))
            message = json.loads(ws.recv(timeout=30))
            ws.send(json.dumps({"type": "text", "text": "Still there?", "language": "en"}))  # the connection goes on
            after = json.loads(ws.recv(timeout=30))
            if after["type"] != "start":  # anything between the error and the next text's start is one too many
                return f"more than one message: {message} {after}"
            while after["type"] not in ("end", "error"):
                after = json.loads(ws.recv(timeout=30))
            return f"{message['type']}: {message.get('message')}" + ("" if after["type"] == "end" else f", then {after}")
    if route == "speak":
        answer = client.post("/api/speak", json=KL)
    elif route == "animate":
        answer = client.post("/api/animate", params=KL, content=wav, headers={"Content-Type": "audio/wav"})
    else:
        answer = client.post("/api/chat", json={"message": KL["text"], "language": KL["language"]})
    return f"{answer.status_code}: {answer.json().get('detail')}"


def _poll_config(url: str, stop: threading.Event, times: list[float], failures: list[str]) -> None:
    with httpx.Client(base_url=url, timeout=10) as client:
        while not stop.is_set():
            started = time.perf_counter()
            try:
                status = client.get("/api/config").status_code
                if status != 200:
                    failures.append(str(status))
            except httpx.HTTPError as exc:
                failures.append(type(exc).__name__)
            times.append((time.perf_counter() - started) * 1e3)
            stop.wait(0.05)


def serve_routes(times: int, wav: bytes) -> tuple[dict, bool]:
    echo = ThreadingHTTPServer(("127.0.0.1", 0), _Echo)
    threading.Thread(target=echo.serve_forever, daemon=True).start()
    report: dict = {}
    ok = True
    chat = f"http://127.0.0.1:{echo.server_address[1]}/chat"
    with running_server("--rate-limit", "0", "--chat-url", chat) as server:
        with httpx.Client(base_url=server.url, timeout=60) as client:
            for route in ("speak", "stream", "animate", "chat"):
                config_ms: list[float] = []
                config_failures: list[str] = []
                stop = threading.Event()
                poller = threading.Thread(target=_poll_config, args=(server.url, stop, config_ms, config_failures))
                poller.start()
                started = time.perf_counter()
                answers: Counter = Counter()
                good: Counter = Counter()
                for i in range(times):
                    answers[_crash(route, client, server.url, wav)] += 1
                    good[client.post("/api/speak", json={"text": f"Good line {route} {i}.", "language": "en"}).status_code] += 1
                stop.set()
                poller.join()
                p95 = statistics.quantiles(config_ms, n=20)[-1]
                report[route] = {
                    "crashing answers": dict(answers),
                    "good answers": dict(good),
                    "config requests": len(config_ms),
                    "config failures": len(config_failures),
                    "config p50 ms": round(statistics.median(config_ms), 1),
                    "config p95 ms": round(p95, 1),
                    "config max ms": round(max(config_ms), 1),
                    "seconds": round(time.perf_counter() - started, 1),
                }
                print(route, json.dumps(report[route]), flush=True)
                one_error = all(a.startswith(("422: espeak-ng crashed", "error: espeak-ng crashed")) for a in answers)
                ok &= one_error and set(good) == {200} and not config_failures and p95 <= 200
            log = server.log.read_text(errors="replace")
            report["server log tracebacks"] = log.count("Traceback")
            report["server log crash warnings"] = log.count("crashed on")
            ok &= report["server log tracebacks"] == 0
    echo.shutdown()
    return report, ok


def batch(lines: int, jobs: int | None) -> tuple[dict, bool]:
    with tempfile.TemporaryDirectory(prefix="vispeech-batch-") as tmp:
        rows = ["id,text,language"] + [f"good{i:03d},This is good line {i}.,en" for i in range(lines - 1)]
        rows.insert(1 + lines // 2, f"crash,{KL['text']},{KL['language']}")
        (Path(tmp) / "job.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
        command = [sys.executable, "-c", "from vispeech.cli import main; main()", "batch", str(Path(tmp) / "job.csv"),
                   "-o", str(Path(tmp) / "out"), "--formats", "json"]
        if jobs is not None:
            command += ["--jobs", str(jobs)]
        started = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True)
        index_path = Path(tmp) / "out" / "index.jsonl"
        index = [json.loads(line) for line in index_path.read_text().splitlines()] if index_path.exists() else []
        statuses = Counter(entry["status"] for entry in index)
        crash = [entry for entry in index if entry["id"] == "crash"]
        report = {
            "jobs": jobs or "default",
            "exit code": done.returncode,
            "index lines": len(index),
            "statuses": dict(statuses),
            "crash line": crash[0]["error"] if crash else None,
            "folders written": sum((Path(tmp) / "out" / e["id"] / "animation.json").is_file() for e in index),
            "seconds": round(time.perf_counter() - started, 1),
        }
    print("batch", json.dumps(report), flush=True)
    ok = done.returncode == 1 and statuses == {"written": lines - 1, "failed": 1} and report["folders written"] == lines - 1
    return report, ok


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--times", type=int, default=100)
    parser.add_argument("--batch", type=int, default=200)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    from vispeech.pipeline import speak

    wav = speak("Hello, how can I help you today?", "en", model="baseline").wav_bytes()
    report, ok = serve_routes(args.times, wav)
    for jobs in (None, 1):
        report[f"batch jobs={jobs or 'default'}"], batch_ok = batch(args.batch, jobs)
        ok &= batch_ok
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    print("PASS" if ok else "FAIL")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
