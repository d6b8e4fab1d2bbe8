"""The guards of vispeech's web servers (``vispeech serve`` and ``vispeech study serve``), as ASGI
middleware and helpers over Starlette alone: body size limits, per-client token buckets, the
Host / Origin allow-list, and secrets kept out of uvicorn's logs."""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import re
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from urllib.parse import urlsplit

from starlette.exceptions import HTTPException

log = logging.getLogger("vispeech.guards")


class TokenBucket:
    """Per-client token buckets: ``rate`` tokens a second, at most ``burst`` saved up.

    :meth:`take` spends ``cost`` tokens of a client (by key, e.g. its IP address) and tells
    whether it had them (a cost above ``burst`` is taken as ``burst``: a full bucket pays for
    anything); :meth:`charge` spends tokens without refusing (the bucket may go into debt,
    down to ``-burst``), for work whose price is known only once it is done. ``rate`` 0 turns
    the limit off. At most ``max_clients`` buckets are kept; beyond that, full (idle) buckets
    are forgotten.
    """

    def __init__(
        self, rate: float, burst: int, max_clients: int = 10_000, clock: Callable[[], float] = time.monotonic
    ) -> None:
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

    def take(self, key: str, cost: float = 1.0) -> bool:
        """Spend ``cost`` of ``key``'s tokens; ``False`` (nothing spent) when it has fewer."""
        if not self.enabled:
            return True
        cost = min(float(self.burst), max(0.0, float(cost)))
        with self._lock:
            tokens, now = self._tokens(key)
            allowed = tokens >= cost - 1e-9
            self._buckets[key] = (tokens - cost if allowed else tokens, now)
            return allowed

    def charge(self, key: str, cost: float) -> None:
        """Spend ``cost`` of ``key``'s tokens even when it has fewer (debt down to ``-burst``)."""
        if not self.enabled:
            return
        with self._lock:
            tokens, now = self._tokens(key)
            self._buckets[key] = (max(-float(self.burst), tokens - max(0.0, float(cost))), now)

    def _tokens(self, key: str) -> tuple[float, float]:
        now = self.clock()
        tokens, then = self._buckets.get(key, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - then) * self.rate)
        if len(self._buckets) >= self.max_clients and key not in self._buckets:
            self._forget_idle(now)
        return tokens, now

    def retry_after(self) -> float:
        """Seconds until an empty bucket holds a token again."""
        return 1.0 / self.rate if self.enabled else 0.0

    def message(self, price: str = "") -> str:
        """Why a client is refused (``price``: what a request costs, said after the limit)."""
        return (
            f"rate limit exceeded: at most {self.rate:g} tokens a second per client "
            f"(bursts of {self.burst}{'; ' + price if price else ''}); retry in {self.retry_after():.1f} s"
        )

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
    try:
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    *headers,
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
    except Exception:  # noqa: BLE001 (the connection broke first, e.g. the server refused a malformed body)
        log.debug("could not send the %d answer: the connection is gone", status)


class _BodyTooLarge(HTTPException):
    """Raised from ``receive`` once a body passes the limit (FastAPI lets HTTP exceptions through)."""


class BodySizeLimit:
    """ASGI middleware: 413 for an HTTP request whose body exceeds ``max_bytes``, or the limit
    ``paths`` gives its path (an audio upload's, say).

    A ``Content-Length`` above the limit is refused before anything is read; a body sent
    without one (chunked) is counted as it arrives and refused once it passes the limit.
    """

    def __init__(self, app, max_bytes: int, paths: Mapping[str, int] | None = None) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.paths = dict(paths or {})

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.paths.get(scope["path"], self.max_bytes)
        message = f"request body too large (limit {limit} bytes)"
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await send_json_error(send, 400, "invalid Content-Length header")
                    return
                if declared > limit:
                    await send_json_error(send, 413, message, [(b"connection", b"close")])
                    return
        received = 0
        started = False

        async def counting_receive():
            nonlocal received
            event = await receive()
            if event["type"] == "http.request":
                received += len(event.get("body", b""))
                if received > limit:
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


def client_key(scope) -> str:
    """The client's IP address from an ASGI scope (``"unknown"`` without one)."""
    client = scope.get("client")
    return str(client[0]) if client else "unknown"


# -- Host and Origin -------------------------------------------------------------------------

LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")
"""The names of this machine, which a server answers to whatever else it allows."""

DEFAULT_ALLOWED_HOSTS = (*LOOPBACK_HOSTS, "testserver")
"""Host names the server answers to by default: loopback (and ``testserver``, Starlette's
TestClient, which no DNS name can be)."""


def hosts_for(bind: str, extra: Iterable[str] = ()) -> tuple[str, ...]:
    """The host names a server listening on ``bind`` answers to: loopback, ``bind`` (unless it is
    every interface) and ``extra``."""
    return tuple(dict.fromkeys((*LOOPBACK_HOSTS, *([bind] if bind not in ("0.0.0.0", "::", "") else []), *extra)))


def _hostname(value: str) -> str | None:
    """The host name of a ``Host`` header value or an origin (lower case, no port, no brackets)."""
    value = value.strip()
    if not value:
        return None
    try:
        parts = urlsplit(value if "//" in value else "//" + value)
        host = parts.hostname
        parts.port  # noqa: B018 (raises on a bad port)
    except ValueError:
        return None
    return host.lower().rstrip(".") if host else None


def request_headers(scope) -> dict[bytes, bytes]:
    return {name.lower(): value for name, value in scope.get("headers", [])}


async def refuse(scope, receive, send, status: int, detail: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """Refuse an HTTP request (JSON error) or a WebSocket handshake (HTTP ``status`` where the server
    can send a denial response, else close 1008 before accepting)."""
    if scope["type"] == "http":
        await send_json_error(send, status, detail, headers)
        return
    event = await receive()  # websocket.connect
    if event.get("type") != "websocket.connect":
        return
    if "websocket.http.response" in scope.get("extensions", {}):
        body = json.dumps({"detail": detail}).encode()
        await send(
            {
                "type": "websocket.http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    *headers,
                ],
            }
        )
        await send({"type": "websocket.http.response.body", "body": body})
    else:
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})


class HostOriginCheck:
    """ASGI middleware against DNS rebinding and cross-site use.

    Every request's ``Host`` must name one of ``allowed_hosts`` (any port; ``"*"`` allows any)
    or be an IP address (a rebinding attack needs a name the attacker controls): 400
    otherwise. A WebSocket handshake, and any HTTP request other than GET / HEAD / OPTIONS,
    that carries an ``Origin`` must come from the server's own origin (the ``Origin``'s host
    and port those of ``Host``) or one of ``allowed_origins`` (host names or full origins such
    as ``https://app.example.com``; ``None``: the allowed hosts): 403 otherwise. Requests
    without an ``Origin`` (not from a browser) pass.
    """

    def __init__(self, app, allowed_hosts: Iterable[str], allowed_origins: Iterable[str] | None = None) -> None:
        self.app = app
        self.hosts = frozenset(h.lower().strip("[]") for h in allowed_hosts)
        origins = list(allowed_origins) if allowed_origins is not None else list(self.hosts)
        self.any_origin = "*" in origins
        self.origins = frozenset(o.lower().rstrip("/") for o in origins if "//" in o)
        self.origin_hosts = frozenset(o.lower().strip("[]") for o in origins if "//" not in o)

    def host_allowed(self, host: str | None) -> bool:
        if host is None:
            return False
        if "*" in self.hosts or host in self.hosts:
            return True
        try:
            ipaddress.ip_address(host)
        except ValueError:
            return False
        return True

    def origin_allowed(self, origin: str, host: str = "") -> bool:
        if self.any_origin:
            return True
        origin = origin.strip().lower().rstrip("/")
        if origin in self.origins or (_hostname(origin) or "\0") in self.origin_hosts:
            return True
        try:
            parts = urlsplit(origin)
            return bool(parts.netloc) and parts.scheme in ("http", "https") and parts.netloc == host.strip().lower()
        except ValueError:
            return False

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = request_headers(scope)
        raw_host = headers.get(b"host", b"").decode("latin-1")
        if not self.host_allowed(_hostname(raw_host)):
            shown = raw_host[:100] or "(none)"
            await refuse(scope, receive, send, 400, f"Host {shown!r} is not allowed (the server's --allow-host list)")
            return
        origin = headers.get(b"origin")
        checks_origin = scope["type"] == "websocket" or scope.get("method", "GET") not in ("GET", "HEAD", "OPTIONS")
        if origin is not None and checks_origin and not self.origin_allowed(origin.decode("latin-1"), raw_host):
            shown = origin.decode("latin-1")[:100]
            await refuse(
                scope, receive, send, 403, f"Origin {shown!r} is not allowed (the server's --allow-origin list)"
            )
            return
        await self.app(scope, receive, send)


# -- secrets in logs -------------------------------------------------------------------------------

_TOKEN_QUERY = re.compile(r"([?&](?:[^=&\s]*token)=)[^&#\s\"]*", re.IGNORECASE)
"""A ``token=`` (or ``admin_token=``, ...) query value in a request line."""

SERVER_LOGGERS = ("uvicorn.access", "uvicorn.error")
"""uvicorn's loggers that write request paths: HTTP requests, and WebSocket handshakes."""


def redact_tokens(text: str) -> str:
    """``text`` with every ``token=`` query value replaced by ``[redacted]``."""
    return _TOKEN_QUERY.sub(r"\1[redacted]", text)


class RedactTokens(logging.Filter):
    """A logging filter that redacts ``token=`` query values (:func:`redact_tokens`) in a record's
    message and its string arguments (uvicorn's access log formats the path from the arguments)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact_tokens(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact_tokens(a) if isinstance(a, str) else a for a in record.args)
        return True


def keep_tokens_out_of_logs(loggers: Iterable[str] = SERVER_LOGGERS) -> None:
    """Redact ``token=`` query values in what ``loggers`` write (once per logger; uvicorn's logging
    set-up keeps a logger's filters)."""
    for name in loggers:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())
