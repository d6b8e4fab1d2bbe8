"""Latency of a chat spoken as its reply streams in: from the first clause's arrival to the first audio.

    python benchmarks/chat_latency.py [--runs 5] [--token-ms 30] [--json OUT]

Starts a fake OpenAI-compatible chat model in this process (it streams a three-sentence reply,
English, Swedish, English, a word every ``--token-ms`` ms, as Server-Sent Events) and `vispeech
serve --chat-url` on it in a subprocess (the default models, no rate limit), then sends a chat
message over ``/api/stream`` ``--runs`` times (after one warm-up), each in the session of the one
before, and times, from the moment the fake model sent the last word of the first clause:
the first ``reply``, ``frames`` and ``audio`` messages, and the ``end``. It also reports the
time from the first word sent to the first audio, the language each sentence was spoken in and
how many messages the model was sent (the history). The acceptance asks for the first audio
within 300 ms of the first clause.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from local_server import running_server

REPLY = "Hello there, it is good to see you. Det här är en mening på svenska. I hope that helps."
FIRST_CLAUSE = "Hello there,"


class FakeModel:
    """A chat model streaming :data:`REPLY` a word at a time; ``sent`` holds when the first word and the
    first clause's last word left, ``requests`` each request's body."""

    def __init__(self, token_seconds: float) -> None:
        self.sent: dict[str, float] = {}
        self.requests: list[dict] = []
        fake = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_POST(self) -> None:  # noqa: N802 (http.server's name)
                fake.requests.append(json.loads(self.rfile.read(int(self.headers["Content-Length"]))))
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Transfer-Encoding", "chunked")
                self.end_headers()
                text = ""
                for word in REPLY.split(" "):
                    time.sleep(token_seconds)
                    piece = word if not text else " " + word
                    self._send({"choices": [{"index": 0, "delta": {"content": piece}, "finish_reason": None}]})
                    text += piece
                    fake.sent.setdefault("first word", time.perf_counter())
                    if text == FIRST_CLAUSE:
                        fake.sent["first clause"] = time.perf_counter()
                self._send({"choices": [{"index": 0, "delta": {}, "finish_reason": "stop"}]})
                self._write(b"data: [DONE]\n\n")
                self.wfile.write(b"0\r\n\r\n")
                self.close_connection = True

            def _send(self, chunk: dict) -> None:
                self._write(f"data: {json.dumps(chunk)}\n\n".encode())

            def _write(self, raw: bytes) -> None:
                self.wfile.write(b"%x\r\n%s\r\n" % (len(raw), raw))
                self.wfile.flush()

            def log_message(self, *args) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}/v1"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()


async def chat_once(url: str, model: FakeModel, session: str | None) -> dict:
    """One chat message over the stream: the times of its messages from the first clause's arrival."""
    import websockets

    model.sent.clear()
    seen: dict[str, float] = {}
    languages: list[tuple[str, str]] = []
    async with websockets.connect(url, max_size=None) as ws:
        await ws.send(json.dumps({"type": "chat", "message": "Say something.", "language": "en", "session": session}))
        async with asyncio.timeout(60):
            async for raw in ws:
                message = json.loads(raw)
                seen.setdefault(message["type"], time.perf_counter())
                if message["type"] == "reply":
                    session = message["session"]
                    languages.append((message["text"], message["language"]))
                elif message["type"] == "error":
                    raise RuntimeError(message["message"])
                elif message["type"] == "end":
                    break
    clause = model.sent["first clause"]
    return {
        **{f"{kind} ms": round((seen[kind] - clause) * 1000, 1) for kind in ("reply", "frames", "audio", "end")},
        "first word to audio ms": round((seen["audio"] - model.sent["first word"]) * 1000, 1),
        "languages": languages,
        "session": session,
        "messages sent to the model": len(model.requests[-1]["messages"]),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--token-ms", type=float, default=30.0)
    parser.add_argument("--json", help="write the report here")
    args = parser.parse_args()
    model = FakeModel(args.token_ms / 1000)
    with running_server("--rate-limit", "0", "--chat-url", model.url, "--chat-model", "fake") as server:
        session = asyncio.run(chat_once(server.stream_url, model, None))["session"]  # warm-up
        runs = []
        for _ in range(args.runs):
            runs.append(asyncio.run(chat_once(server.stream_url, model, session)))
            print(json.dumps(runs[-1], ensure_ascii=False), flush=True)
    report = {
        "runs": len(runs),
        "token ms": args.token_ms,
        **{
            f"{kind} median": statistics.median(run[kind] for run in runs)
            for kind in ("reply ms", "frames ms", "audio ms", "end ms", "first word to audio ms")
        },
        "audio ms max": max(run["audio ms"] for run in runs),
        "languages": runs[-1]["languages"],
        "messages sent to the model": [run["messages sent to the model"] for run in runs],
    }
    print(json.dumps(report, indent=2, ensure_ascii=False))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(report, out, indent=2, ensure_ascii=False)
    swedish = [language for text, language in report["languages"] if "svenska" in text]
    return 0 if report["audio ms max"] <= 300 and swedish == ["sv"] else 1


if __name__ == "__main__":
    sys.exit(main())
