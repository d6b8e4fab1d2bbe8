"""Malformed requests against the server: no 5xx, no internal error, still serving afterwards.

    python benchmarks/fuzz_server.py [--requests 1000] [--seed 0] [--url http://127.0.0.1:8000]

Without ``--url`` it starts `vispeech serve` on 127.0.0.1 on a free port in a subprocess
(no rate limit, a temporary cache). The requests, drawn with ``--seed``:

- ``POST /api/speak`` and ``/api/chat`` with fuzzed JSON: wrong types, missing and extra
  fields, NaN and huge numbers, oversize and odd text (control characters, emoji, only
  punctuation), deep nesting, bodies that are not JSON or not UTF-8;
- bodies over the size limit, with a Content-Length and chunked;
- raw HTTP requests (written on a socket, so nothing normalises them) for bad paths:
  traversal (``/static/../../etc/passwd``, ``%2e%2e``, ``%252e``, backslashes, NUL), odd
  methods and headers, a broken Content-Length;
- WebSocket ``/api/stream`` messages: not JSON, binary, wrong types, bad phones (out of
  order, NaN, unknown symbols, too many seconds), oversize, and a WebSocket handshake on a
  plain route;
- odd ``Host``, ``Origin`` and ``Authorization`` headers (foreign, missing, malformed ports,
  IPv6 brackets), on HTTP and on the WebSocket handshake (refused with 400 / 401 / 403).

With ``--token`` the server wants a token: most requests carry it, some a wrong, empty or
malformed one.

It fails (exit 1) on any 5xx, any ``internal server error`` stream message or 1011 close,
any traversal answer that leaks a file, a server log with a traceback, or a server that
no longer answers ``GET /api/config``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import random
import socket
import sys
import time
from collections import Counter
from urllib.parse import urlsplit

import httpx
from local_server import running_server
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from vispeech.phonetics.inventory import get_inventory

ODD_TEXT = ["", " ", "\u0000", "\t\n", "!!!", "...", "😀" * 10, "a" * 1001, "a" * 999, "é" * 600,
            "<script>alert(1)</script>", "Robert'); DROP TABLE utterances;--", "%s%s%n", "\ud7ff", "١٢٣",
            "Hej på dig", "Hello", "1,000,000 $", "x " * 400, "\u202e\u200b", "a" * 100_000]
ODD_VALUES = [None, True, False, 0, -1, 1e308, -1e308, 0.5, 2.5, 3, "", "en", "sv", "fr", "EN", [], {},
              [1, 2], {"a": 1}, "baseline", "../../etc/passwd", 10**40]
TRAVERSALS = [
    "/static/../../etc/passwd", "/static/%2e%2e/%2e%2e/etc/passwd", "/static/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
    "/static/..%2f..%2fetc%2fpasswd", "/static/%252e%252e/%252e%252e/etc/passwd", "/static/..\\..\\etc\\passwd",
    "/static/....//....//etc/passwd", "/static/%c0%ae%c0%ae/etc/passwd", "/static/face2d.js%00.html",
    "/static//etc/passwd", "/static/./../app.py", "/static/chunks/../../app.py", "/avatar.glb/../../etc/passwd",
    "/api/audio/..%2f..%2fetc%2fpasswd.wav", "/api/audio/../../etc/passwd.wav", "/api/audio/%2e%2e.wav",
    "/../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/player/../../etc/passwd", "//etc/passwd",
    "/static/" + "a/" * 2000, "/api/audio/" + "f" * 5000 + ".wav", "/static/%ff%fe", "/static/\u00e9",
    "/api/config?x=" + "%" * 100, "/docs/../openapi.json", "/api/stream", "/api/speak/../speak",
]
CONTENT_TYPES = ["application/json", "text/plain", "application/x-www-form-urlencoded",
                 "multipart/form-data; boundary=x", "application/json; charset=latin-1"]
METHODS = ["GET", "HEAD", "POST", "PUT", "DELETE", "OPTIONS", "PATCH", "TRACE", "FOO", "G\x00T"]
ODD_HEADERS = [{"host": "evil.example"}, {"host": "127.0.0.1:99999"}, {"host": "[::1]:8000"}, {"host": ""},
               {"origin": "https://evil.example"}, {"origin": "null"}, {"origin": "http://localhost:1"},
               {"authorization": "Bearer"}, {"authorization": "Bearer " + "x" * 5000}, {"authorization": "Basic Zm9v"},
               {"cookie": "vispeech_token=wrong; x=y"}, {"cookie": ";;;=="}]
SECRET_MARKERS = (b"root:", b"[boot loader]", b"import ", b"def ")


def fuzz_json(rng: random.Random, fields: dict) -> bytes:
    """A mutation of a valid request body (bytes; sometimes not JSON at all)."""
    body = dict(fields)
    kind = rng.randrange(8)
    if kind == 0:
        return json.dumps(rng.choice(ODD_VALUES)).encode()
    if kind == 1:
        return rng.choice([b"{", b"{bad json", b"\xff\xfe\x00", b'{"text": NaN}', b'{"text": "a"', b"[" * 30000,
                           b'{"text":"a","rate":Infinity}', b"", b"null", b'{"text":"\\ud800"}', b"\x00" * 100])
    for _ in range(rng.randint(1, 3)):
        key = rng.choice([*fields, "extra", "__proto__", ""])
        action = rng.randrange(4)
        if action == 0:
            body.pop(key, None)
        elif action == 1:
            body[key] = rng.choice(ODD_VALUES)
        else:
            body[key] = rng.choice(ODD_TEXT)
    if kind == 2:
        body = {"a": body}
        for _ in range(rng.randint(1, 200)):
            body = {"a": body}
    return json.dumps(body, allow_nan=True).encode("utf-8", "surrogatepass")


def raw_request(host: str, port: int, data: bytes, timeout: float = 10.0) -> tuple[int | None, bytes]:
    """Send ``data`` on a fresh socket; the status code (``None`` without an answer) and the body."""
    with socket.create_connection((host, port), timeout=timeout) as sock:
        sock.sendall(data)
        chunks = []
        with contextlib.suppress(OSError):
            while chunk := sock.recv(65536):
                chunks.append(chunk)
    answer = b"".join(chunks)
    if not answer.startswith(b"HTTP/"):
        return None, answer
    head, _, body = answer.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), body


def phones_message(rng: random.Random) -> str:
    symbols = list(get_inventory(rng.choice(["en", "sv"])).symbols) + ["xyz", "", "AA9", "'a", "sil" * 5]
    t = rng.choice([0.0, -1.0, 5.0, 599.0])
    phones = []
    for _ in range(rng.choice([0, 1, 3, 20, 501])):
        step = rng.choice([0.05, 0.1, -0.05, 0.0, 20.0])
        phones.append({"symbol": rng.choice(symbols), "start": t, "end": t + step, "stress": rng.choice([0, 1, 3, -1])})
        t += max(step, 0.0)
    message = {"type": "phones", "phones": phones, "final": rng.random() < 0.3}
    if rng.random() < 0.5:
        message["language"] = rng.choice(["en", "sv", "fr", None])
    text = json.dumps(message)
    return text.replace("0.05", "NaN", 1) if rng.random() < 0.1 else text


def ws_message(rng: random.Random) -> str | bytes:
    kind = rng.randrange(7)
    if kind == 0:
        return rng.choice(["", "nonsense", "[1]", "null", "{", '"text"', "{}", b"\x00\x01", b"binary"])
    if kind == 1:
        return json.dumps({"type": rng.choice(["text", "phones", "start", "", None, 1]),
                           "text": rng.choice(ODD_TEXT[:-1]), "language": rng.choice(ODD_VALUES)})
    if kind == 2:
        return json.dumps({"type": "text", "text": rng.choice(ODD_TEXT[:-1]) or "hi",
                           "model": rng.choice(["nope", None, "../x", 5]), "rate": rng.choice([1.0, 0.1, "x"])})
    if kind == 3:
        return json.dumps({"type": "text", "text": "x" * 100_000})  # oversize: the server closes
    return phones_message(rng)


class Fuzzer:
    def __init__(self, url: str, seed: int, token: str | None = None) -> None:
        self.url = url.rstrip("/")
        parts = urlsplit(self.url)
        self.host, self.port = parts.hostname, parts.port or 80
        self.ws_url = self.url.replace("http://", "ws://") + "/api/stream"
        self.rng = random.Random(seed)
        self.token = token
        self.headers = {"authorization": f"Bearer {token}"} if token else {}
        self.statuses: Counter = Counter()
        self.failures: list[str] = []
        self.sent = 0

    def record(self, what: str, status: int | str | None) -> None:
        """Count one request by its answer: an HTTP status, ``None`` (no answer) or a WebSocket outcome."""
        self.sent += 1
        self.statuses[status] += 1
        if isinstance(status, int) and status >= 500:
            self.failures.append(f"{status} for {what[:120]!r}")

    def http(self, client: httpx.Client, n: int) -> None:
        rng = self.rng
        for _ in range(n):
            kind = rng.randrange(10)
            if kind < 5:
                path, fields = rng.choice([("/api/speak", {"text": "Hello", "language": "en", "model": None, "rate": 1.0}),
                                           ("/api/chat", {"message": "hej", "language": "sv", "speak": True})])
                body = fuzz_json(rng, fields)
                headers = {"content-type": rng.choice(CONTENT_TYPES)}
                if rng.random() < 0.15:
                    headers.update(rng.choice(ODD_HEADERS))
                self.record(f"POST {path} {body[:80]!r}", client.post(path, content=body, headers=headers).status_code)
            elif kind == 5:
                size = rng.choice([65 * 1024, 200 * 1024, 2 * 1024 * 1024])
                self.record(f"POST huge {size}", client.post("/api/speak", content=b"{" + b" " * size).status_code)
            elif kind == 6:
                size = rng.choice([70 * 1024, 1024 * 1024])
                chunks = (b"x" * 8192 for _ in range(size // 8192))
                self.record(f"POST chunked {size}", client.post("/api/chat", content=chunks).status_code)
            elif kind == 7:
                path = rng.choice(TRAVERSALS)
                method = rng.choice(METHODS[:3])
                status, body = raw_request(self.host, self.port,
                                           f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode(
                                               "utf-8", "surrogatepass"))
                self.record(f"{method} {path}", status)
                if status == 200 and "etc" in path and any(marker in body for marker in SECRET_MARKERS):
                    self.failures.append(f"traversal leaked a file: {path}")
            elif kind == 8:
                self.raw_odd(rng)
            else:
                method = rng.choice(METHODS[2:8])
                path = rng.choice(["/api/speak", "/api/chat", "/api/config", "/", "/avatar.glb", "/static/face2d.js"])
                self.record(f"{method} {path}", client.request(method, path).status_code)

    def raw_odd(self, rng: random.Random) -> None:
        request = rng.choice([
            b"POST /api/speak HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: abc\r\nConnection: close\r\n\r\n{}",
            b"POST /api/speak HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 99999999999\r\nConnection: close\r\n\r\n{}",
            b"POST /api/speak HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: -1\r\nConnection: close\r\n\r\n",
            b"POST /api/speak HTTP/1.1\r\nHost: 127.0.0.1\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\nzz\r\n",
            b"G\x00T / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
            b"GET / HTTP/9.9\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
            b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 70000 + b"\r\nConnection: close\r\n\r\n",
            b"\r\n\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: \xff\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: 127.0.0.1:abc\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: [::1\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: \xff\xfe\r\nConnection: close\r\n\r\n",
            b"GET /api/config HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n",
            (b"POST /api/chat HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: null\r\nContent-Length: 2\r\n"
             b"Connection: close\r\n\r\n{}"),
            (b"POST /api/chat HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: http://[\r\nContent-Length: 2\r\n"
             b"Connection: close\r\n\r\n{}"),
            (b"POST /api/speak HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer \xff\r\nContent-Length: 2\r\n"
             b"Connection: close\r\n\r\n{}"),
            (b"GET /api/stream?token=%ff%fe&token=x HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: Upgrade\r\n"
             b"Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
             b"Origin: https://evil.example\r\n\r\n"),
        ])
        status, _ = raw_request(self.host, self.port, request)
        self.record(f"raw {request[:60]!r}", status)

    def websocket(self, n: int) -> None:
        rng = self.rng
        done = 0
        while done < n:
            if rng.random() < 0.05:
                origin = rng.choice(["https://evil.example", "null", "http://127.0.0.1.evil.example", "http://["])
                try:
                    with connect(self.ws_url, open_timeout=10, additional_headers={**self.headers, "Origin": origin}):
                        self.record(f"ws from Origin {origin}", 101)
                        self.failures.append(f"a WebSocket from Origin {origin} was accepted")
                except InvalidStatus as exc:
                    self.record(f"ws from Origin {origin}", exc.response.status_code)
                done += 1
                continue
            if rng.random() < 0.05:
                try:
                    with connect(self.url.replace("http://", "ws://") + "/api/speak", open_timeout=10):
                        self.record("ws handshake on /api/speak", 101)
                except InvalidStatus as exc:
                    self.record("ws handshake on /api/speak", exc.response.status_code)
                done += 1
                continue
            with connect(self.ws_url, open_timeout=10, max_size=None, additional_headers=self.headers) as ws:
                for _ in range(min(20, n - done)):
                    message = ws_message(rng)
                    done += 1
                    try:
                        ws.send(message)
                        ws.send('{"type":"fuzz-sentinel"}')  # always answered with an error: marks the end
                        while True:
                            reply = json.loads(ws.recv(timeout=30))
                            if reply.get("type") == "error" and "internal" in reply.get("message", ""):
                                self.failures.append(f"internal error for ws message {str(message)[:120]!r}")
                            if reply.get("type") == "error" and "fuzz-sentinel" in reply.get("message", ""):
                                break
                        self.record(f"ws {str(message)[:80]}", "ws answered")
                    except ConnectionClosed as exc:
                        code = exc.rcvd.code if exc.rcvd else None
                        self.record(f"ws {str(message)[:80]}", f"ws closed {code}")
                        if code == 1011:
                            self.failures.append(f"ws closed with 1011 after {str(message)[:120]!r}")
                        break


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=1000, help="requests in all (HTTP and WebSocket messages)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--url", help="fuzz this running server instead of starting one (loopback only!)")
    parser.add_argument("--token", help="start the server with this token (requests mostly carry it)")
    args = parser.parse_args()
    n = min(max(args.requests, 10), 10_000)

    def fuzz(url: str) -> tuple[Fuzzer, int]:
        fuzzer = Fuzzer(url, args.seed, args.token)
        with httpx.Client(base_url=url, timeout=30, headers=fuzzer.headers) as client:
            fuzzer.http(client, n * 4 // 5)
            fuzzer.websocket(n - n * 4 // 5)
            return fuzzer, client.get("/api/config").status_code

    started = time.perf_counter()
    log = ""
    if args.url:
        fuzzer, config_status = fuzz(args.url)
    else:
        with running_server("--rate-limit", "0", *(["--token", args.token] if args.token else [])) as server:
            fuzzer, config_status = fuzz(server.url)
            log = server.log.read_text(errors="replace")
    if config_status != 200:
        fuzzer.failures.append(f"GET /api/config answered {config_status} after fuzzing")
    if "Traceback" in log:
        fuzzer.failures.append("the server log holds a traceback:\n" + log[log.index("Traceback"):][:3000])
    print(f"{fuzzer.sent} malformed requests in {time.perf_counter() - started:.1f} s")
    print("answers: " + ", ".join(f"{status}: {count}" for status, count in sorted(fuzzer.statuses.items(), key=str)))
    print(f"GET /api/config afterwards: {config_status}")
    for failure in fuzzer.failures[:20]:
        print(f"FAIL {failure}")
    print("ok: no 5xx, server still serving" if not fuzzer.failures else f"{len(fuzzer.failures)} failures")
    return 1 if fuzzer.failures else 0


if __name__ == "__main__":
    sys.exit(main())
