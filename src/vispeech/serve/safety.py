"""``vispeech serve``'s own defences: the token (ASGI middleware), the rate limit's refusal and the
WebSocket slots per address and network (the shared guards are :mod:`vispeech.guards`; the work
pool is :mod:`vispeech.serve.pool`)."""

from __future__ import annotations

import hmac
import math
from urllib.parse import parse_qs

from vispeech.guards import TokenBucket, refuse, request_headers


class RateLimited(Exception):
    """A client ran out of rate-limit tokens (429 with ``Retry-After``, or a stream error)."""

    def __init__(self, bucket: TokenBucket) -> None:
        super().__init__(
            bucket.message("a request costs a token per 100 characters of text, second of phones or 4 s of audio")
        )
        self.retry_after = max(1, math.ceil(bucket.retry_after()))


# -- the token -------------------------------------------------------------------------------------

TOKEN_COOKIE = "vispeech_token"
"""Cookie set by a page opened with ``?token=...``: the pages' own requests carry it."""

PAGE_PATHS = frozenset({"/", "/player", "/viewer"})
OPEN_API_PATHS = frozenset({"/api/config"})


class TokenAuth:
    """ASGI middleware: with a ``token``, the API wants it (401 otherwise).

    Open without it: the pages, ``/static/...``, ``/avatar.glb``, ``/api/config``, ``/docs``
    and ``/openapi.json``. Every other ``/api/...`` route (speak, chat, audio, the stream)
    wants ``Authorization: Bearer <token>``, or the ``vispeech_token`` cookie, or (the
    WebSocket and ``GET /api/audio``, which a browser cannot give headers) a ``token`` query
    parameter. A page opened with the right ``?token=`` sets the cookie (HttpOnly,
    SameSite=Strict), so the web app's own requests carry it.
    """

    def __init__(self, app, token: str | None) -> None:
        self.app = app
        self.token = token.encode() if token else None

    def _matches(self, given: str | bytes | None) -> bool:
        if given is None or self.token is None:
            return False
        given = given.encode("utf-8", "replace") if isinstance(given, str) else given
        return hmac.compare_digest(given, self.token)

    def _query_token(self, scope) -> str | None:
        try:
            values = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token")
        except ValueError:
            return None
        return values[0] if values else None

    def authorised(self, scope) -> bool:
        headers = request_headers(scope)
        auth = headers.get(b"authorization", b"")
        if auth[:7].lower() == b"bearer " and self._matches(auth[7:].strip()):
            return True
        for part in headers.get(b"cookie", b"").split(b";"):
            name, _, value = part.strip().partition(b"=")
            if name == TOKEN_COOKIE.encode() and self._matches(value):
                return True
        query_allowed = scope["type"] == "websocket" or scope["path"].startswith("/api/audio/")
        return query_allowed and self._matches(self._query_token(scope))

    async def __call__(self, scope, receive, send) -> None:
        if self.token is None or scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        path = scope["path"]
        if scope["type"] == "http" and path in PAGE_PATHS and self._matches(self._query_token(scope)):
            cookie = f"{TOKEN_COOKIE}={self.token.decode()}; Path=/; HttpOnly; SameSite=Strict".encode()

            async def send_with_cookie(event):
                if event["type"] == "http.response.start":
                    event = {**event, "headers": [*event.get("headers", []), (b"set-cookie", cookie)]}
                await send(event)

            await self.app(scope, receive, send_with_cookie)
            return
        if path.startswith("/api/") and path not in OPEN_API_PATHS and not self.authorised(scope):
            await refuse(
                scope,
                receive,
                send,
                401,
                "a token is required: send Authorization: Bearer <token>",
                [(b"www-authenticate", b'Bearer realm="vispeech"')],
            )
            return
        await self.app(scope, receive, send)


# -- connections -----------------------------------------------------------------------------------


class ConnectionCounter:
    """Open WebSocket connections, server-wide and per client IP, against their caps."""

    def __init__(self, max_total: int, max_per_ip: int) -> None:
        self.max_total = max_total
        self.max_per_ip = max_per_ip
        self.total = 0
        self.per_ip: dict[str, int] = {}

    def open(self, ip: str) -> str | None:
        """Count a new connection of ``ip``; the reason it is refused (then nothing is counted)."""
        if self.total >= self.max_total:
            return f"server busy: {self.max_total} streams open, try again later"
        if self.per_ip.get(ip, 0) >= self.max_per_ip:
            return f"too many streams from your address (at most {self.max_per_ip} at once)"
        self.total += 1
        self.per_ip[ip] = self.per_ip.get(ip, 0) + 1
        return None

    def close(self, ip: str) -> None:
        self.total -= 1
        left = self.per_ip.get(ip, 1) - 1
        if left > 0:
            self.per_ip[ip] = left
        else:
            self.per_ip.pop(ip, None)
