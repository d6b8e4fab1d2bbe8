"""WebSocket slots that cannot be hoarded: only valid work keeps a connection open, caps per address
and per network, and the connection idle longest gives way to a new one when the server is full."""

from __future__ import annotations

import contextlib
import time

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from vispeech.serve import ServeConfig, create_app, safety  # noqa: E402
from vispeech.serve.connection import GAVE_WAY  # noqa: E402
from vispeech.serve.safety import GIVE_WAY_AFTER_S, NoSlot, Slots, network_of  # noqa: E402


def config(tmp_path, **changes) -> ServeConfig:
    settings = {"cache": tmp_path / "c.sqlite3", "rate_limit": 0, "default_model": "baseline",
                "stream_model": "baseline", **changes}
    return ServeConfig(**settings)


def from_header(app):
    """``app``, with each request coming from the address in its ``x-client`` header (a test hook:
    TestClient connects from one address only)."""
    async def wrapped(scope, receive, send):
        address = dict(scope.get("headers", [])).get(b"x-client")
        if scope["type"] in ("http", "websocket") and address:
            scope = {**scope, "client": (address.decode(), 50000)}
        await app(scope, receive, send)
    return wrapped


def receive_until(ws, kinds=("end", "error")) -> list[dict]:
    messages = []
    while True:
        messages.append(ws.receive_json())
        if messages[-1]["type"] in kinds:
            return messages


def closed_with(ws) -> tuple[str, int]:
    """The error a closing connection sends, and its close code."""
    message = ws.receive_json()
    assert message["type"] == "error"
    with pytest.raises(WebSocketDisconnect) as closed:
        ws.receive_json()
    return message["message"], closed.value.code


def test_networks_are_ipv4_24_and_ipv6_64():
    assert network_of("192.0.2.77") == network_of("::ffff:192.0.2.1") == "192.0.2.0/24"
    assert network_of("2001:db8:1:2:aaaa::1") == network_of("2001:db8:1:2::ffff") == "2001:db8:1:2::/64"
    assert network_of("2001:db8:1:3::1") != network_of("2001:db8:1:2::1")
    assert network_of("unknown") == "unknown"


def test_slots_cap_address_and_network_and_evict_the_longest_idle():
    now = [0.0]
    slots = Slots(max_total=3, max_per_ip=2, max_per_network=2, clock=lambda: now[0])
    gave_way = []
    first = slots.open("10.0.0.1", lambda: gave_way.append("first"))
    now[0] = 1.0
    second = slots.open("10.0.0.1", lambda: gave_way.append("second"))
    with pytest.raises(NoSlot, match="from your address"):
        slots.open("10.0.0.1", lambda: None)
    with pytest.raises(NoSlot, match="from your network 10.0.0.0/24"):
        slots.open("10.0.0.2", lambda: None)
    now[0] = 2.0
    third = slots.open("10.0.1.1", lambda: gave_way.append("third"))
    slots.worked(first)  # valid work: now the second is idle longest
    now[0] = 3.0
    slots.open("10.0.2.1", lambda: None)
    assert gave_way == ["second"] and slots.total == 3 and slots.per_ip["10.0.0.1"] == 1
    slots.close(second)  # its own close after giving way changes nothing
    assert slots.total == 3
    for slot in slots.slots:
        slot.busy = True  # all working: nobody gives way
    with pytest.raises(NoSlot, match="server busy"):
        slots.open("10.0.3.1", lambda: None)
    third.busy = False
    with pytest.raises(NoSlot, match="server busy"):  # third opened 1 s ago: not idle long enough to go
        slots.open("10.0.3.1", lambda: None)
    now[0] = 4.0
    slots.open("10.0.3.1", lambda: None)
    assert gave_way == ["second", "third"]


def test_a_connection_that_keeps_working_never_gives_way():
    """A live microphone sends a chunk every 20 ms, finished between them (not busy): however long
    it has been open, it is not idle, and a newcomer to a full server is refused rather than it."""
    now = [0.0]
    slots = Slots(max_total=2, max_per_ip=2, max_per_network=2, clock=lambda: now[0])
    gave_way = []
    streams = [slots.open(f"10.0.{n}.1", lambda n=n: gave_way.append(n)) for n in range(2)]
    for step in range(1, 500):  # 10 s of chunks
        now[0] = step * 0.02
        for slot in streams:
            slots.worked(slot)
    with pytest.raises(NoSlot, match="server busy"):
        slots.open("10.0.9.1", lambda: None)
    now[0] += 0.5
    slots.worked(streams[1])  # the first microphone stopped half a second before the second
    now[0] += GIVE_WAY_AFTER_S  # now both may give way: the first, idle longer, does
    slots.open("10.0.9.1", lambda: None)
    assert gave_way == [0]


def test_invalid_messages_do_not_keep_a_connection_open(tmp_path):
    with TestClient(create_app(config(tmp_path, idle_timeout=0.5))) as client:
        with client.websocket_connect("/api/stream") as ws:
            for _ in range(100):  # far longer than the idle timeout, were it reset
                ws.send_text("not json")
                time.sleep(0.05)
                message = ws.receive_json()
                if "no valid message" in message["message"]:
                    break
                assert message["type"] == "error"
            else:
                pytest.fail("invalid messages kept the connection open")
            with pytest.raises(WebSocketDisconnect) as closed:
                ws.receive_json()
            assert closed.value.code == 1001


def test_hoarded_slots_give_way_to_a_new_client(tmp_path, monkeypatch):
    """Every slot held by connections sending invalid messages, from addresses in different
    networks: a new client is served, and the connection idle longest is closed to make room
    (without waiting the seconds a connection must idle first)."""
    monkeypatch.setattr(safety, "GIVE_WAY_AFTER_S", 0.0)
    settings = config(tmp_path, max_streams=6, max_streams_per_ip=1, max_streams_per_network=3, idle_timeout=30)
    with TestClient(from_header(create_app(settings))) as client, contextlib.ExitStack() as stack:
        held = []
        for n in range(6):
            connect = client.websocket_connect("/api/stream", headers={"x-client": f"198.51.{n // 3}.{n % 3 + 1}"})
            held.append(stack.enter_context(connect))
            held[-1].send_text("{}")
            assert held[-1].receive_json()["type"] == "error"
        with client.websocket_connect("/api/stream", headers={"x-client": "198.51.1.9"}) as ws:
            assert "from your network 198.51.1.0/24" in closed_with(ws)[0]  # its address holds none
        for ws in held[1:]:  # keep them busy being wrong: none of that is valid work
            ws.send_text("{}")
            assert ws.receive_json()["type"] == "error"
        with client.websocket_connect("/api/stream", headers={"x-client": "203.0.113.5"}) as newcomer:
            newcomer.send_json({"type": "text", "text": "Hello."})
            assert receive_until(newcomer)[-1]["type"] == "end"
            assert closed_with(held[0]) == (GAVE_WAY, 1013)
        for ws in held[1:]:
            ws.send_text("{}")  # still open
            assert ws.receive_json()["type"] == "error"
