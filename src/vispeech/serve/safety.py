"""Input limits of the server: request body size and a per-client rate limit (ASGI middleware)."""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Iterable

from starlette.exceptions import HTTPException


class TokenBucket:
    """Per-client token buckets: ``rate`` tokens a second, at most ``burst`` saved up.

    :meth:`take` spends one token of a client (by key, e.g. its IP address) and tells
    whether there was one. ``rate`` 0 turns the limit off. At most ``max_clients`` buckets
    are kept; beyond that, full (idle) buckets are forgotten.
    """

    def __init__(self, rate: float, burst: int, max_clients: int = 10_000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not (math.isfinite(rate) and rate >= 0) or burst < 1:
            raise ValueError("rate must be >= 0 and burst >= 1")
        self.rate = float(rate)
        self.burst = int(burst)
        self.max_clients = max_clients
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, time)
        self._lock = threading.Lock()

    @property
    def enabled(self) -> bool:
        return self.rate > 0

    def take(self, key: str) -> bool:
        """Spend one of ``key``'s tokens; ``False`` when it has none left."""
        if not self.enabled:
            return True
        with self._lock:
            now = self.clock()
            tokens, then = self._buckets.get(key, (float(self.burst), now))
            tokens = min(float(self.burst), tokens + (now - then) * self.rate)
            if len(self._buckets) >= self.max_clients and key not in self._buckets:
                self._forget_idle(now)
            allowed = tokens >= 1.0
            self._buckets[key] = (tokens - 1.0 if allowed else tokens, now)
            return allowed

    def retry_after(self) -> float:
        """Seconds until an empty bucket holds a token again."""
        return 1.0 / self.rate if self.enabled else 0.0

    def message(self) -> str:
        return (f"rate limit exceeded: at most {self.rate:g} requests a second per client "
                f"(bursts of {self.burst}); retry in {self.retry_after():.1f} s")

    def _forget_idle(self, now: float) -> None:
        full = [k for k, (tokens, then) in self._buckets.items() if tokens + (now - then) * self.rate >= self.burst]
        for key in full:
            del self._buckets[key]
        if len(self._buckets) >= self.max_clients:  # all busy: drop the oldest
            oldest = sorted(self._buckets, key=lambda k: self._buckets[k][1])[: len(self._buckets) // 2]
            for key in oldest:
                del self._buckets[key]


async def send_json_error(send, status: int, detail: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """Send a complete ``{"detail": ...}`` JSON response through an ASGI ``send``."""
    body = json.dumps({"detail": detail}).encode()
    await send({
        "type": "http.response.start",
        "status": status,
        "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), *headers],
    })
    await send({"type": "http.response.body", "body": body})


class _BodyTooLarge(HTTPException):
    """Raised from ``receive`` once a body passes the limit (FastAPI lets HTTP exceptions through)."""


class BodySizeLimit:
    """ASGI middleware: 413 for an HTTP request whose body exceeds ``max_bytes``.

    A ``Content-Length`` above the limit is refused before anything is read; a body sent
    without one (chunked) is counted as it arrives and refused once it passes the limit.
    """

    def __init__(self, app, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        message = f"request body too large (limit {self.max_bytes} bytes)"
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await send_json_error(send, 400, "invalid Content-Length header")
                    return
                if declared > self.max_bytes:
                    await send_json_error(send, 413, message, [(b"connection", b"close")])
                    return
        received = 0
        started = False

        async def counting_receive():
            nonlocal received
            event = await receive()
            if event["type"] == "http.request":
                received += len(event.get("body", b""))
                if received > self.max_bytes:
                    raise _BodyTooLarge(413, message)
            return event

        async def tracking_send(event):
            nonlocal started
            if event["type"] == "http.response.start":
                started = True
            await send(event)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except _BodyTooLarge:
            if not started:
                await send_json_error(send, 413, message, [(b"connection", b"close")])


class RateLimit:
    """ASGI middleware: 429 with a ``Retry-After`` when a client runs out of tokens.

    Only HTTP requests whose path is in ``paths`` spend tokens; the client is the peer's IP
    address (a proxy in front should do its own limiting).
    """

    def __init__(self, app, bucket: TokenBucket, paths: Iterable[str]) -> None:
        self.app = app
        self.bucket = bucket
        self.paths = frozenset(paths)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http" and scope["path"] in self.paths and not self.bucket.take(client_key(scope)):
            retry = str(max(1, math.ceil(self.bucket.retry_after()))).encode()
            await send_json_error(send, 429, self.bucket.message(), [(b"retry-after", retry)])
            return
        await self.app(scope, receive, send)


def client_key(scope) -> str:
    """The client's IP address from an ASGI scope (``"unknown"`` without one)."""
    client = scope.get("client")
    return str(client[0]) if client else "unknown"
