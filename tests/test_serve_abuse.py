"""The server under abuse: the work pool, priced rate limits, stream caps and timeouts, Host / Origin
checks, the token, the cache's byte cap and unguessable audio ids (loopback and TestClient only)."""

from __future__ import annotations

import asyncio
import hashlib
import json
import sqlite3
import threading
import time

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402
from starlette.testclient import WebSocketDenialResponse  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from vispeech.serve import CacheKey, ServeConfig, UtteranceCache, create_app  # noqa: E402
from vispeech.guards import TokenBucket  # noqa: E402
from vispeech.streaming import PhoneStream  # noqa: E402


def config(tmp_path, **changes) -> ServeConfig:
    settings = {"cache": tmp_path / "c.sqlite3", "rate_limit": 0, "default_model": "baseline",
                "stream_model": "baseline", **changes}
    return ServeConfig(**settings)


def steady_phones(start: float, end: float, step: float = 0.1) -> list[dict]:
    """Alternating vowels and consonants from ``start`` to ``end`` s."""
    phones, t, i = [], start, 0
    while t < end - 1e-9:
        phones.append({"symbol": ("AA1", "M")[i % 2], "start": round(t, 6), "end": round(min(t + step, end), 6)})
        t += step
        i += 1
    return phones


def receive_until(ws, kinds=("end", "error")) -> list[dict]:
    messages = []
    while True:
        messages.append(ws.receive_json())
        if messages[-1]["type"] in kinds:
            return messages


# -- Host and Origin --------------------------------------------------------------------------------

def test_host_header_must_be_allowed(tmp_path):
    with TestClient(create_app(config(tmp_path))) as client:
        assert client.get("/api/config").status_code == 200  # testserver
        assert client.get("/api/config", headers={"host": "localhost:8000"}).status_code == 200
        assert client.get("/api/config", headers={"host": "[::1]:8000"}).status_code == 200
        refused = client.get("/api/config", headers={"host": "rebind.attacker.example:8000"})
        assert refused.status_code == 400 and "not allowed" in refused.json()["detail"]
        assert client.post("/api/speak", json={"text": "hi"}, headers={"host": "evil.example"}).status_code == 400
        assert client.get("/api/config", headers={"host": "192.168.1.5:8000"}).status_code == 200  # an address
        assert client.get("/api/config", headers={"host": "[fe80::1]"}).status_code == 200
        assert client.get("/api/config", headers={"host": "192.168.1.5.evil.example"}).status_code == 400
    with TestClient(create_app(config(tmp_path, allowed_hosts=("*",)))) as anything:
        assert anything.get("/api/config", headers={"host": "whatever.example"}).status_code == 200


def test_a_foreign_origin_is_refused_on_the_websocket_and_on_posts(tmp_path):
    with TestClient(create_app(config(tmp_path))) as client:
        with pytest.raises(WebSocketDenialResponse) as denied:
            with client.websocket_connect("/api/stream", headers={"origin": "https://evil.example"}):
                pass
        assert denied.value.status_code == 403 and "Origin" in denied.value.json()["detail"]
        with client.websocket_connect("/api/stream", headers={"origin": "http://localhost:8000"}) as ws:
            ws.send_json({"type": "text", "text": "Hi."})
            assert receive_until(ws)[-1]["type"] == "end"
        post = client.post("/api/chat", json={"message": "hi", "speak": False}, headers={"origin": "null"})
        assert post.status_code == 403
        same = client.post("/api/chat", json={"message": "hi", "speak": False},
                           headers={"origin": "http://127.0.0.1:8000"})
        assert same.status_code == 200
        assert client.get("/api/config", headers={"origin": "https://evil.example"}).status_code == 200  # reads pass
        lan = {"host": "192.168.1.5:8000"}  # the server's own origin, reached by its address
        assert client.post("/api/chat", json={"message": "hi", "speak": False},
                           headers={**lan, "origin": "http://192.168.1.5:8000"}).status_code == 200
        assert client.post("/api/chat", json={"message": "hi", "speak": False},
                           headers={**lan, "origin": "http://192.168.1.6:8000"}).status_code == 403
    allowed = config(tmp_path, allowed_origins=("https://app.example.com",))
    with TestClient(create_app(allowed)) as client, client.websocket_connect(
            "/api/stream", headers={"origin": "https://app.example.com"}) as ws:
        ws.send_json({"type": "text", "text": "Hi."})
        assert receive_until(ws)[-1]["type"] == "end"


# -- the token --------------------------------------------------------------------------------------

def test_with_a_token_the_api_wants_it(tmp_path):
    static = tmp_path / "static"
    static.mkdir()
    (static / "index.html").write_text("<!doctype html>", encoding="utf-8")
    with TestClient(create_app(config(tmp_path, token="s3cret", static_dir=static))) as client:
        assert client.get("/api/config").json()["token_required"] is True
        assert client.get("/").status_code == 200 and "set-cookie" not in client.get("/").headers
        assert client.get("/static/face2d.js").status_code == 200
        refused = client.post("/api/speak", json={"text": "hi"})
        assert refused.status_code == 401 and refused.headers["www-authenticate"].startswith("Bearer")
        assert client.post("/api/speak", json={"text": "hi"},
                           headers={"authorization": "Bearer wrong"}).status_code == 401
        assert client.post("/api/chat", json={"message": "hi"}).status_code == 401
        assert client.post("/api/speak?token=s3cret", json={"text": "hi"}).status_code == 401  # no query on POST
        spoken = client.post("/api/speak", json={"text": "hi"}, headers={"authorization": "Bearer s3cret"})
        assert spoken.status_code == 200
        audio = spoken.json()["audio_url"]
        assert client.get(audio).status_code == 401
        assert client.get(audio + "?token=s3cret").status_code == 200
        with pytest.raises(WebSocketDenialResponse) as denied:
            with client.websocket_connect("/api/stream"):
                pass
        assert denied.value.status_code == 401
        with client.websocket_connect("/api/stream?token=s3cret") as ws:
            ws.send_json({"type": "text", "text": "Hi."})
            assert receive_until(ws)[-1]["type"] == "end"
        with client.websocket_connect("/api/stream", headers={"authorization": "Bearer s3cret"}) as ws:
            ws.send_json({"type": "text", "text": "Hi."})
            assert receive_until(ws)[-1]["type"] == "end"
        # a page opened with the token sets the cookie, and the page's own requests carry it
        page = client.get("/?token=s3cret")
        assert page.status_code == 200 and "HttpOnly" in page.headers["set-cookie"]
        assert client.post("/api/chat", json={"message": "hi", "speak": False}).status_code == 200
        assert client.get(audio).status_code == 200
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "text", "text": "Hi."})
            assert receive_until(ws)[-1]["type"] == "end"


def test_without_a_token_nothing_is_asked(tmp_path):
    with TestClient(create_app(config(tmp_path))) as client:
        assert client.get("/api/config").json()["token_required"] is False
        assert client.post("/api/chat", json={"message": "hi", "speak": False}).status_code == 200


# -- priced rate limit, stream limits, timeouts ------------------------------------------------------

def test_token_bucket_prices_and_debt():
    now = [0.0]
    bucket = TokenBucket(rate=1.0, burst=10, clock=lambda: now[0])
    assert bucket.take("a", 6) and not bucket.take("a", 6) and bucket.take("a", 4)
    assert bucket.take("b", 50)  # a full bucket pays for anything
    assert not bucket.take("b", 0.5)
    bucket.charge("c", 25)  # debt, down to -burst
    now[0] += 10.0
    assert not bucket.take("c", 0.5)  # -10 + 10 = 0 tokens
    now[0] += 1.0
    assert bucket.take("c", 1.0)


def test_stream_messages_are_priced_by_their_work(tmp_path):
    with TestClient(create_app(config(tmp_path, rate_limit=0.001, burst=5, piece_seconds=10))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 3.0)})  # 3 s: 3 tokens
            assert receive_until(ws, ("frames", "error"))[-1]["type"] == "frames"
            ws.send_json({"type": "phones", "phones": steady_phones(3.0, 6.0)})  # 3 more: only 2 left
            error = ws.receive_json()
            assert error["type"] == "error" and "rate limit" in error["message"]
            ws.send_json({"type": "phones", "phones": steady_phones(3.0, 4.0), "final": True})  # 1 s fits
            assert receive_until(ws)[-1]["type"] == "end"
        with client.websocket_connect("/api/stream") as ws:  # the same client: 1 token left
            ws.send_json({"type": "text", "text": "x" * 300})  # 3 tokens
            assert "rate limit" in ws.receive_json()["message"]
        speak = client.post("/api/speak", json={"text": "hello " * 50})  # 300 characters: 3 tokens
        assert speak.status_code == 429 and int(speak.headers["retry-after"]) >= 1


def test_listen_timings_are_priced_by_the_seconds_they_add(tmp_path):
    """Timings drive a timed listen stream's frames as phones drive a phone stream's: a message
    costs a token per second it adds (the audio is priced on its own)."""
    with TestClient(create_app(config(tmp_path, rate_limit=0.001, burst=5))) as client:
        with client.websocket_connect("/api/listen") as ws:
            ws.send_json({"type": "start", "sample_rate": 16000, "timings": "words"})  # 0.05
            assert ws.receive_json()["type"] == "start"
            words = [{"text": "map", "start": 0.0, "end": 3.0}]  # 3 s: 3 tokens
            ws.send_json({"type": "words", "words": words})
            assert ws.receive_json()["type"] == "frames"
            ws.send_json({"type": "words", "words": [{"text": "map", "start": 3.0, "end": 6.0}]})  # 1.95 left
            error = ws.receive_json()
            assert error["type"] == "error" and "rate limit" in error["message"]


def test_phones_per_message_and_per_stream_are_bounded(tmp_path):
    with TestClient(create_app(config(tmp_path, max_message_seconds=5, max_stream_seconds=8, piece_seconds=10))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 6.0, 0.2)})
            refused = ws.receive_json()
            assert refused["type"] == "error" and "at most 5 s" in refused["message"]
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 4.0, 0.2)})
            messages = receive_until(ws, ("frames",))
            assert messages[0]["type"] == "start"
            ws.send_json({"type": "phones", "phones": steady_phones(4.0, 9.0, 0.2)})
            refused = ws.receive_json()
            assert refused["type"] == "error" and "at most 8 s" in refused["message"]
            ws.send_json({"type": "phones", "phones": steady_phones(4.0, 8.0, 0.2), "final": True})
            assert receive_until(ws)[-1] == {"type": "end", "n_frames": 240, "duration": 8.0}


def test_long_phone_messages_are_pushed_in_pieces(tmp_path):
    with TestClient(create_app(config(tmp_path, piece_seconds=1.0))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 16.0), "final": True})
            messages = receive_until(ws)
    frames = [m for m in messages if m["type"] == "frames"]
    assert len(frames) >= 5  # a frames message a piece: 1, 2, 4, 4, 4 and the last 1 s
    assert frames[0]["start_frame"] == 0 and len(frames[0]["frames"]) <= 30  # the first piece: 1 s at most
    assert len(frames) <= 7  # pieces grow: not 16 of 1 s
    assert [m["start_frame"] for m in frames] == [sum(len(f["frames"]) for f in frames[:i]) for i in range(len(frames))]
    assert sum(len(m["frames"]) for m in frames) == messages[-1]["n_frames"] == 480


def test_streams_per_ip_are_capped(tmp_path):
    with TestClient(create_app(config(tmp_path, max_streams_per_ip=1))) as client:
        with client.websocket_connect("/api/stream") as first:
            with client.websocket_connect("/api/stream") as second:
                assert "too many streams from your address" in second.receive_json()["message"]
                with pytest.raises(WebSocketDisconnect) as closed:
                    second.receive_json()
                assert closed.value.code == 1013
            first.send_json({"type": "text", "text": "Still served."})
            assert receive_until(first)[-1]["type"] == "end"
        with client.websocket_connect("/api/stream") as again:  # the first one's slot is free again
            again.send_json({"type": "text", "text": "Hi."})
            assert receive_until(again)[-1]["type"] == "end"


def test_idle_and_long_connections_are_closed(tmp_path):
    with TestClient(create_app(config(tmp_path, idle_timeout=0.3))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "text", "text": "Hi."})
            assert receive_until(ws)[-1]["type"] == "end"
            started = time.monotonic()
            message = ws.receive_json()
            assert message["type"] == "error" and "no valid message for 0.3 s" in message["message"]
            with pytest.raises(WebSocketDisconnect) as closed:
                ws.receive_json()
            assert closed.value.code == 1001 and time.monotonic() - started < 3
        assert client.app.state.service.active_streams == 0
    with TestClient(create_app(config(tmp_path, idle_timeout=10, stream_timeout=0.6))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 0.5)})
            receive_until(ws, ("frames",))
            message = ws.receive_json()
            assert message["type"] == "error" and "open 0.6 s" in message["message"]
            with pytest.raises(WebSocketDisconnect) as closed:
                ws.receive_json()
            assert closed.value.code == 1001


# -- the work pool (its fairness: test_serve_pool.py) ---------------------------------------------

def test_a_full_queue_answers_503(tmp_path):
    gate = threading.Event()
    with TestClient(create_app(config(tmp_path, workers=1, max_queue=1))) as client:
        service = client.app.state.service
        real = service.speak

        def slow_speak(*args):
            gate.wait(10)
            return real(*args)

        service.speak = slow_speak
        answers = []
        threads = [threading.Thread(target=lambda t=t: answers.append(
            client.post("/api/speak", json={"text": t}).status_code)) for t in ("One.", "Two.")]
        for thread in threads:
            thread.start()
            time.sleep(0.3)
        busy = client.post("/api/speak", json={"text": "Three."})
        gate.set()
        for thread in threads:
            thread.join(20)
        assert busy.status_code == 503 and "busy" in busy.json()["detail"] and busy.headers["retry-after"] == "1"
        assert sorted(answers) == [200, 200]
        assert client.get("/api/config").status_code == 200


def test_a_client_that_leaves_stops_its_work(tmp_path, monkeypatch):
    pushes = []
    real_push = PhoneStream.push

    def slow_push(self, phones):
        pushes.append(len(phones))
        time.sleep(0.1)
        return real_push(self, phones)

    monkeypatch.setattr(PhoneStream, "push", slow_push)
    with TestClient(create_app(config(tmp_path, piece_seconds=0.5))) as client:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": steady_phones(0.0, 20.0)})  # 40 pieces, 4 s of work
            assert ws.receive_json()["type"] == "start"
            ws.receive_json()  # the first piece's frames
        time.sleep(1.0)
        done = len(pushes)
        time.sleep(0.5)
        assert len(pushes) == done < 15  # stopped soon after the client left, and stays stopped
        service = client.app.state.service
        assert service.active_streams == 0 and service.pool.queued == 0


# -- the cache --------------------------------------------------------------------------------------

def test_cache_byte_cap_evicts_the_least_recently_used(tmp_path):
    cache = UtteranceCache(tmp_path / "c.sqlite3", max_bytes=100)
    keys = [CacheKey(f"text {i}", "en", "en-us", 1.0, "baseline", "v1", 30.0, "arkit") for i in range(4)]
    for key in keys[:2]:
        cache.put(key, b"w" * 38, "{}")  # 40 bytes each
    assert cache.get(keys[0]) is not None  # keys[0] used after keys[1]
    cache.put(keys[2], b"w" * 38, "{}")
    assert cache.total_bytes() == 80 and cache.get(keys[1]) is None and cache.get(keys[0]) is not None
    cache.put(keys[3], b"w" * 500, "{}")  # larger than the cap: kept, alone
    assert len(cache) == 1 and cache.audio(cache.entry_id(keys[3])) == b"w" * 500
    cache.close()


def test_audio_ids_cannot_be_guessed_from_the_text(tmp_path):
    key = CacheKey("my secret", "en", "en-us", 1.0, "baseline", "v1", 30.0, "arkit")
    first, second = UtteranceCache(tmp_path / "a.sqlite3"), UtteranceCache(tmp_path / "b.sqlite3")
    assert first.entry_id(key) != second.entry_id(key)  # a secret per cache file
    public = hashlib.sha256(key.canonical()).hexdigest()[:32]
    assert first.entry_id(key) != public
    first.put(key, b"wav", "{}")
    first.close()
    again = UtteranceCache(tmp_path / "a.sqlite3")  # the same file keeps its secret: same request, same id
    assert again.get(key).id == again.entry_id(key) and again.audio(again.entry_id(key)) == b"wav"
    assert again.audio(public) is None
    again.close()


@pytest.mark.parametrize("version", [None, "2"])
def test_a_cache_file_of_an_old_layout_is_emptied_once(tmp_path, version):
    """Layout 1 (no meta table) and 2 (no output scale) are emptied; what is written then stays."""
    path = tmp_path / "old.sqlite3"
    db = sqlite3.connect(path)
    db.executescript("""CREATE TABLE utterances (id TEXT PRIMARY KEY, text TEXT NOT NULL, language TEXT NOT NULL,
        voice TEXT NOT NULL, rate REAL NOT NULL, model TEXT NOT NULL, model_version TEXT NOT NULL, fps REAL NOT NULL,
        wav BLOB NOT NULL, animation TEXT NOT NULL, created REAL NOT NULL, used REAL NOT NULL);""")
    db.execute("INSERT INTO utterances VALUES ('0123', 't', 'en', 'en-us', 1, 'm', 'v', 30, x'00', '{}', 0, 0)")
    if version is not None:
        db.executescript("CREATE TABLE meta (name TEXT PRIMARY KEY, value TEXT NOT NULL);")
        db.execute("INSERT INTO meta VALUES ('schema', ?)", (version,))
    db.commit()
    db.close()
    cache = UtteranceCache(path)
    assert len(cache) == 0
    key = CacheKey("t", "en", "en-us", 1.0, "m", "v", 30.0, "arkit")
    cache.put(key, b"wav", json.dumps({}))
    assert cache.get(key) is not None
    cache.close()
    again = UtteranceCache(path)
    assert again.get(key) is not None
    again.close()


# -- property-based: whatever arrives, no 5xx and no internal error ----------------------------------

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=30),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)
FIELD_VALUES = st.one_of(JSON, st.sampled_from(["en", "sv", "fr", "baseline", "nope", "", "Hello.", "x" * 1001]))
PHONE = st.fixed_dictionaries(
    {"symbol": st.sampled_from(["AA1", "M", "sil", "a", "xyz", "", "P"]),
     "start": st.floats(-1, 700) | st.just(float("nan")), "end": st.floats(-1, 700) | st.just(float("nan"))},
    optional={"stress": st.integers(-2, 4)})
STREAM_MESSAGE = st.one_of(
    JSON,
    st.fixed_dictionaries({"type": st.sampled_from(["text", "phones", "start", ""])},
                          optional={"text": FIELD_VALUES, "language": FIELD_VALUES, "model": FIELD_VALUES,
                                    "rate": FIELD_VALUES, "final": st.booleans(),
                                    "phones": st.lists(PHONE, max_size=8)}),
)
PROPERTY = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    cache = tmp_path_factory.mktemp("abuse") / "c.sqlite3"
    settings_ = ServeConfig(cache=cache, rate_limit=0, default_model="baseline", stream_model="baseline")
    with TestClient(create_app(settings_)) as client:
        yield client


@PROPERTY
@given(path=st.sampled_from(["/api/speak", "/api/chat"]),
       body=st.dictionaries(st.sampled_from(["text", "message", "lang", "model", "rate", "speak"]), FIELD_VALUES,
                            max_size=5) | JSON)
def test_any_json_body_gets_no_5xx(served, path, body):
    response = served.post(path, content=json.dumps(body, allow_nan=True), headers={"content-type": "application/json"})
    assert response.status_code < 500, response.text


@PROPERTY
@given(message=STREAM_MESSAGE)
def test_any_stream_message_gets_an_answer_and_the_stream_goes_on(served, message):
    with served.websocket_connect("/api/stream") as ws:
        ws.send_text(json.dumps(message, allow_nan=True))
        ws.send_text('{"type": "sentinel"}')  # always refused: marks the end of the answers
        while True:
            reply = ws.receive_json()
            assert not (reply["type"] == "error" and "internal" in reply["message"]), (message, reply)
            if reply["type"] == "error" and "sentinel" in reply["message"]:
                break
