"""``vispeech serve``'s own defences: the token (ASGI middleware), the rate limit's refusal and the
WebSocket slots, capped per address and per network (the shared guards are :mod:`vispeech.guards`; the work
pool is :mod:`vispeech.serve.pool`)."""

from __future__ import annotations

import hmac
import ipaddress
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
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


# -- WebSocket slots -------------------------------------------------------------------------------


def network_of(ip: str) -> str:
    """The network the per-network cap counts ``ip`` in: its /24 (IPv4, an IPv4-mapped IPv6 address
    too) or its /64 (IPv6); anything else (``"unknown"``) stands for itself."""
    try:
        address = ipaddress.ip_address(ip)
    except ValueError:
        return ip
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return str(ipaddress.ip_network(f"{address}/{24 if address.version == 4 else 64}", strict=False))


class NoSlot(Exception):
    """A WebSocket connection refused a slot (the message says why)."""


@dataclass(eq=False)
class Slot:
    """One open WebSocket connection's place: its address and network, when it last finished valid
    work (or opened), whether it is working now, and how to ask it to give way."""

    ip: str
    network: str
    active: float
    give_way: Callable[[], None]
    busy: bool = False


GIVE_WAY_AFTER_S = 2.0
"""Seconds without valid work after which a connection may have to give way to a new one: a live
microphone's chunks come every 20 ms, so one that streams never counts as idle."""


class Slots:
    """Open WebSocket connections against their caps: ``max_total`` in all, ``max_per_ip`` from one
    address, ``max_per_network`` from one network (:func:`network_of`).

    A new connection past an address's or a network's cap is refused; one that finds the server
    full takes the slot of the connection idle longest (not working now, and without valid work
    for :data:`GIVE_WAY_AFTER_S` at least), which is asked to give way; with none such it is
    refused. Only valid work keeps a connection from going idle (:meth:`worked`).
    """

    def __init__(
        self, max_total: int, max_per_ip: int, max_per_network: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.max_total = max_total
        self.max_per_ip = max_per_ip
        self.max_per_network = max_per_network
        self.clock = clock
        self.slots: set[Slot] = set()
        self.per_ip: Counter[str] = Counter()
        self.per_network: Counter[str] = Counter()

    @property
    def total(self) -> int:
        return len(self.slots)

    def open(self, ip: str, give_way: Callable[[], None]) -> Slot:
        """A slot for a new connection of ``ip`` (``give_way``: called should it have to make room);
        :class:`NoSlot` when it gets none."""
        network = network_of(ip)
        if self.per_ip[ip] >= self.max_per_ip:
            raise NoSlot(f"too many streams from your address (at most {self.max_per_ip} at once)")
        if self.per_network[network] >= self.max_per_network:
            raise NoSlot(f"too many streams from your network {network} (at most {self.max_per_network} at once)")
        if self.total >= self.max_total:
            now = self.clock()
            idle = [slot for slot in self.slots if not slot.busy and now - slot.active >= GIVE_WAY_AFTER_S]
            if not idle:
                raise NoSlot(f"server busy: all {self.max_total} streams are in use, try again later")
            longest = min(idle, key=lambda slot: slot.active)
            self.close(longest)
            longest.give_way()
        slot = Slot(ip, network, self.clock(), give_way)
        self.slots.add(slot)
        self.per_ip[ip] += 1
        self.per_network[network] += 1
        return slot

    def worked(self, slot: Slot) -> None:
        """``slot``'s connection has just finished valid work: it is no longer idle."""
        slot.active = self.clock()

    def idle_for(self, slot: Slot) -> float:
        """Seconds since ``slot``'s connection last finished valid work (or opened)."""
        return self.clock() - slot.active

    def close(self, slot: Slot) -> None:
        """Free ``slot`` (again: nothing)."""
        if slot not in self.slots:
            return
        self.slots.remove(slot)
        for counts, key in ((self.per_ip, slot.ip), (self.per_network, slot.network)):
            counts[key] -= 1
            if counts[key] <= 0:
                del counts[key]
