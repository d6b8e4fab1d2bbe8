"""Streaming: clause splitting, the /api/stream WebSocket (text and phones), the phone streams."""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass

import numpy as np
import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from vispeech.alignment.phones import Phone, PhoneSequence  # noqa: E402
from vispeech.errors import VispeechError  # noqa: E402
from vispeech.models.streams import WindowStream  # noqa: E402
from vispeech.models.registry import create_model  # noqa: E402
from vispeech.models.rules.cohen_massaro import CohenMassaro  # noqa: E402
from vispeech.pipeline import animate, speak  # noqa: E402
from vispeech.serve import PhoneStream, ServeConfig, create_app, open_phone_stream, safety, split_clauses  # noqa: E402
from vispeech.streaming import POSTPROCESS_LOOKAHEAD, STREAM_CHANNELS  # noqa: E402

# "hello world", then a pause: (symbol, start, end)
HELLO = [("sil", 0.0, 0.1), ("HH", 0.1, 0.16), ("AH0", 0.16, 0.22), ("L", 0.22, 0.28), ("OW1", 0.28, 0.45),
         ("W", 0.45, 0.52), ("ER1", 0.52, 0.65), ("L", 0.65, 0.7), ("D", 0.7, 0.76), ("sil", 0.76, 1.0)]


def phone_dicts(rows) -> list[dict]:
    return [{"symbol": symbol, "start": start, "end": end} for symbol, start, end in rows]


def phones_of(rows) -> list[Phone]:
    return [Phone(symbol, start, end) for symbol, start, end in rows]


def offline(rows, language: str = "en") -> PhoneSequence:
    return PhoneSequence([Phone(s.rstrip("012"), a, b, None, int(s[-1]) if s[-1].isdigit() else 0)
                          for s, a, b in rows], language)


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    cache = tmp_path_factory.mktemp("stream") / "cache.sqlite3"
    # the window stream over a data-free model (the shipped default network streams itself)
    config = ServeConfig(cache=cache, rate_limit=0, default_model="baseline", stream_model="baseline")
    with TestClient(create_app(config)) as client:
        yield client


def receive_until_end(ws) -> list[dict]:
    messages = []
    while True:
        message = ws.receive_json()
        messages.append(message)
        if message["type"] in ("end", "error"):
            return messages


def test_a_clause_that_leaves_late_is_announced(client, monkeypatch):
    import time

    from vispeech.text_stream import SpeechTimeline

    original, placed = SpeechTimeline.place, []

    def slow_after_first(self, voiced):  # an overloaded server: the second clause comes 1.5 s later
        placed.append(voiced)
        if len(placed) == 2:
            time.sleep(1.5)
        return original(self, voiced)

    monkeypatch.setattr(SpeechTimeline, "place", slow_after_first)
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": "Hello, my good friend.", "language": "en"})
        messages = receive_until_end(ws)
    warnings = [m for m in messages if m["type"] == "warning"]
    assert len(warnings) == 1 and warnings[0]["code"] == "late"
    first_clause = next(m["start"] for m in messages[messages.index(warnings[0]):] if m["type"] == "audio")
    assert 1.5 - first_clause - 0.3 < warnings[0]["seconds"] < 1.5 - first_clause + 0.5  # the sleep past the due time
    assert "overloaded" in warnings[0]["message"] and messages[-1]["type"] == "end"

    monkeypatch.setattr(SpeechTimeline, "place", original)
    with client.websocket_connect("/api/stream") as ws:  # in time: no warning
        ws.send_json({"type": "text", "text": "Hello, my good friend.", "language": "en"})
        assert "warning" not in [m["type"] for m in receive_until_end(ws)]


def test_clauses_voiced_together_each_get_their_voice_or_their_error():
    from vispeech.models.registry import load_model
    from vispeech.text_stream import SpeechTimeline, voice_clauses

    model = load_model("grid-tdnn-lowlatency")
    timelines = [SpeechTimeline(model, fps=fps) for fps in (30.0, 30.0, 25.0)]
    asked = [timelines[0].clause("Hello,", "en"), timelines[1].clause("Hej!", "sv", last=True),
             timelines[2].clause("Good day.", "en", last=True)]
    unsayable = asked[1]._replace(rate=9.0)
    voiced = voice_clauses(model, [asked[0], unsayable, asked[2]])
    assert isinstance(voiced[1], VispeechError) and "rate must be between" in str(voiced[1])
    for timeline, clause, one in zip((timelines[0], timelines[2]), (asked[0], asked[2]), (voiced[0], voiced[2])):
        assert one.text == clause.text and one.channels == clause.channels
        duration = len(one.pcm) / one.sample_rate
        assert one.phones.duration == pytest.approx(duration)
        assert one.values.shape == (one.phones.n_frames(clause.fps), len(clause.channels))
        assert not one.pcm[: round(clause.lead * one.sample_rate)].any()  # the silence before the first clause
        messages = timeline.place(one)
        assert messages[0]["type"] == "start" and messages[0]["channels"] == list(clause.channels)
        frames = sum(len(m["frames"]) for m in messages if m["type"] == "frames")
        assert frames == math.ceil(duration * clause.fps - 1e-9)


def test_split_clauses():
    assert split_clauses("Hello, world! How are you? Fine; thanks.") == [
        "Hello,", "world!", "How are you?", "Fine;", "thanks."]
    assert split_clauses("It costs 3.50 or 1,000 kronor.") == ["It costs 3.50 or 1,000 kronor."]
    assert split_clauses("Hej!\nHur mår du ... ?") == ["Hej!", "Hur mår du ... ?"]
    assert split_clauses("... Hello") == ["... Hello"]
    assert split_clauses(" !! ") == ["!!"]


def test_text_stream_gives_audio_and_frames_of_matching_length(client):
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": "Hello there, my friend. How are you today?", "language": "en"})
        messages = receive_until_end(ws)
    kinds = [m["type"] for m in messages]
    assert kinds[0] == "start" and kinds[-1] == "end" and "error" not in kinds
    start = messages[0]
    assert start["fps"] == 30.0 and start["sample_rate"] == 22050 and start["model"] == "baseline"
    assert kinds.index("frames") < kinds.index("audio")  # the animation leads the sound

    audio = [m for m in messages if m["type"] == "audio"]
    assert [m["seq"] for m in audio] == list(range(len(audio)))
    samples = 0
    for m in audio:  # chunks of at most 100 ms, back to back
        assert m["start"] == pytest.approx(samples / 22050)
        n = len(base64.b64decode(m["pcm16"])) // 2
        assert 0 < n <= 2205
        samples += n

    frames = [m for m in messages if m["type"] == "frames"]
    n_frames = 0
    for m in frames:
        assert m["start_frame"] == n_frames
        assert all(len(row) == len(start["channels"]) for row in m["frames"])
        n_frames += len(m["frames"])
    assert abs(n_frames - samples / 22050 * 30.0) <= 1
    assert messages[-1]["n_frames"] == n_frames == math.ceil(samples / 22050 * 30.0 - 1e-6)
    assert len(audio) > 3 * 3  # three clauses, each spoken in several chunks


def test_phones_stream_over_the_websocket(client):
    rows = HELLO
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "phones", "language": "en", "phones": phone_dicts(rows[:4])})
        start = ws.receive_json()
        assert start["type"] == "start" and start["fps"] == 30.0 and start["lookahead"] == 2 + POSTPROCESS_LOOKAHEAD
        first = ws.receive_json()  # phones up to 0.28 s: frames 0..8 known, 0..6 predicted, 0..4 post-processed
        assert first["type"] == "frames" and first["start_frame"] == 0 and len(first["frames"]) == 5
        ws.send_json({"type": "phones", "phones": phone_dicts(rows[4:]), "final": True})
        messages = receive_until_end(ws)
    assert [m["type"] for m in messages][-1] == "end"
    frames = first["frames"] + [row for m in messages if m["type"] == "frames" for row in m["frames"]]
    assert len(frames) == messages[-1]["n_frames"] == 30
    reference = animate(offline(rows), "baseline").select(start["channels"]).values
    assert np.abs(np.array(frames) - reference).mean() < 0.02


def test_bad_stream_messages_get_errors_and_the_stream_goes_on(client):
    with client.websocket_connect("/api/stream") as ws:
        for bad, words in [
            ("not json", "not valid JSON"),
            ("[1, 2]", "JSON object"),
            ('{"type": "shout"}', '"type" must be'),
            ('{"text": "hi"}', '"type" is missing'),
            ('{"type": "text", "text": ""}', "text"),
            ('{"type": "text", "text": "hi", "language": "xx"}', "unknown language"),
            ('{"type": "text", "text": "hi", "vioce": "f3"}', "unknown field 'vioce'"),
            ('{"type": "text", "text": "hi", "model": "nope"}', "unknown model"),
            ('{"type": "phones", "phones": [{"symbol": "AA", "start": 0, "end": NaN}]}', "finite"),
        ]:
            ws.send_text(bad)
            reply = ws.receive_json()
            assert reply["type"] == "error" and words in reply["message"], (bad, reply)
        ws.send_bytes(b"\x00\x01")
        assert "JSON text" in ws.receive_json()["message"]
        # a phone stream: out-of-order phones are refused, the stream stays open
        ws.send_json({"type": "phones", "phones": [{"symbol": "sil", "start": 0, "end": 0.5}]})
        assert ws.receive_json()["type"] == "start"
        assert ws.receive_json()["type"] == "frames"
        ws.send_json({"type": "phones", "phones": [{"symbol": "AA", "start": 0.2, "end": 0.3}]})
        assert "before the previous one ends" in ws.receive_json()["message"]
        ws.send_json({"type": "phones", "phones": [{"symbol": "xyz", "start": 0.5, "end": 0.6}]})
        assert "unknown phone symbol" in ws.receive_json()["message"]
        ws.send_json({"type": "text", "text": "hi"})
        assert "phone stream is open" in ws.receive_json()["message"]
        ws.send_json({"type": "phones", "phones": [{"symbol": "AA1", "start": 0.5, "end": 0.6}], "final": True})
        tail = receive_until_end(ws)
        assert tail[-1] == {"type": "end", "n_frames": 18, "duration": 0.6}
        ws.send_json({"type": "text", "text": "Still here."})
        assert receive_until_end(ws)[-1]["type"] == "end"
        ws.send_text("x" * 70_000)
        assert "too large" in ws.receive_json()["message"]
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
        assert closed.value.code == 1009


def test_stream_rate_limit_and_stream_count(tmp_path, monkeypatch):
    monkeypatch.setattr(safety, "GIVE_WAY_AFTER_S", 0.0)  # the first gives way though it worked just now
    config = ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0.001, burst=1, max_streams=1)
    with TestClient(create_app(config)) as limited, limited.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": "One."})
        assert receive_until_end(ws)[-1]["type"] == "end"
        ws.send_json({"type": "text", "text": "Two."})
        assert "rate limit" in ws.receive_json()["message"]
        with limited.websocket_connect("/api/stream") as second:  # the idle first one gives way
            assert "gave way to a new one" in ws.receive_json()["message"]
            second.send_json({"type": "text", "text": "Two."})
            assert "rate limit" in second.receive_json()["message"]  # the same client's bucket


def push_each(stream, phones, fps: float, lookahead: int) -> np.ndarray:
    """Push ``phones`` one at a time, checking that each push gives the next frames, and every frame
    once the phones cover ``lookahead`` frames after it; then finish. All the frames."""
    chunks = []
    for phone in phones:
        start, rows = stream.push([phone])
        assert start == sum(len(c) for c in chunks) and rows.shape[1] == len(stream.channels)
        assert stream.emitted == max(0, math.ceil(phone.end * fps - 1e-6) - lookahead)
        chunks.append(rows)
    start, rows = stream.finish()
    assert start == sum(len(c) for c in chunks)
    return np.concatenate(chunks + [rows])


def test_phone_stream_gives_each_frame_after_its_lookahead():
    model = create_model("baseline")
    stream = open_phone_stream(model, "en")
    assert isinstance(stream, PhoneStream)
    assert (stream.fps, stream.lookahead) == (30.0, model.lookahead + POSTPROCESS_LOOKAHEAD) == (30.0, 4)
    assert len(push_each(stream, phones_of(HELLO), 30.0, stream.lookahead)) == 30
    with pytest.raises(VispeechError, match="ended"):
        stream.push(phones_of(HELLO[:1]))
    stream.close()  # again: no harm


def test_window_stream_gives_raw_frames_after_the_models_lookahead():
    model = create_model("cohen-massaro")
    stream = model.stream("en", 30.0)
    assert isinstance(stream, WindowStream) and (stream.fps, stream.lookahead) == (30.0, model.lookahead) == (30.0, 2)
    assert stream.channels == model.channels
    frames = push_each(stream, list(offline(HELLO)), 30.0, 2)
    assert len(frames) == 30
    with pytest.raises(VispeechError, match="ended"):
        stream.push(list(offline(HELLO))[:1])


class FarSighted(CohenMassaro):
    """Cohen-Massaro streamed with a look-ahead of 10 frames."""

    @property
    def lookahead(self) -> int:
        return 10


def test_window_stream_matches_offline_prediction():
    """With the whole context the window reproduces the offline track; with a long look-ahead the
    windows come close (a frame off would not)."""
    model = create_model("cohen-massaro")
    reference = model.predict(offline(HELLO), 30.0).values
    exact = WindowStream(model, "en", 30.0, context=10.0)
    first = exact.push(list(offline(HELLO)))[1]
    assert np.allclose(np.concatenate([first, exact.finish()[1]]), reference, atol=1e-9)
    windowed = WindowStream(FarSighted(), "en", 30.0, context=1.0)
    assert windowed.lookahead == 10
    frames = np.concatenate([windowed.push([p])[1] for p in offline(HELLO)] + [windowed.finish()[1]])
    assert np.abs(frames - reference).mean() < 1e-3
    assert np.abs(frames[1:] - reference[:-1]).mean() > 5e-3


def test_phone_stream_post_processes_as_animate_does():
    """On the whole context the stream's post-processed frames are animate's; frame by frame close to them."""
    model = create_model("ohman")
    track = animate(offline(HELLO), model)  # the preset the model recommends, at 30 fps
    whole = PhoneStream(model, "en", context=10.0)
    assert whole.channels == STREAM_CHANNELS and set(track.channels) < set(STREAM_CHANNELS)
    reference = track.select(STREAM_CHANNELS).values  # the cheeks and nose ohman does not drive at rest
    first = whole.push(phones_of(HELLO))[1]
    assert np.allclose(np.concatenate([first, whole.finish()[1]]), reference, atol=1e-9)
    frames = push_each(open_phone_stream(model, "en"), phones_of(HELLO), 30.0, 4)
    assert np.abs(frames - reference).mean() < 0.02


def test_phone_stream_refuses_bad_phones():
    stream = PhoneStream(create_model("baseline"), "sv")
    for bad, words in [([Phone("a", 0.2, 0.1)], "end after"), ([Phone("AA", 0.0, 0.1)], "unknown phone"),
                       ([Phone("a", 0.0, 30.0)], "more than"), ([Phone("a", float("nan"), 0.1)], "end after")]:
        with pytest.raises(VispeechError, match=words):
            stream.push(bad)
    assert stream.push([Phone("'a", 0.0, 0.2)])[1].shape[1] == len(stream.channels)
    with pytest.raises(VispeechError, match="before the previous one ends"):
        stream.push([Phone("a", 0.1, 0.3)])


@dataclass
class _Example:
    phones: PhoneSequence
    track: object


def test_model_stream_runs_the_models_own_streaming(tmp_path):
    require_module("torch", "torch (the train extra)")
    from vispeech.models.networks.tdnn import RecurrentStream

    examples = [_Example(offline(HELLO), animate(offline(HELLO), "baseline", fps=60.0)),
                _Example(offline(HELLO[:5]), animate(offline(HELLO[:5]), "baseline", fps=60.0))]
    model = create_model("tdnn-lowlatency", epochs=1, hidden=4,
                         targets=["jawOpen", "mouthClose", "mouthFunnel"]).fit(examples, progress=False)
    assert model.fps_ == 60.0 and model.lookahead == 2
    # the network's own stream: at its 60 fps 2 frames behind, at 30 fps 1, equal to predict at either
    for fps, lookahead in ((60.0, 2), (30.0, 1)):
        raw = model.stream("en", fps)
        assert isinstance(raw, RecurrentStream) and (raw.fps, raw.lookahead) == (fps, lookahead)
        frames = push_each(raw, list(offline(HELLO)), fps, lookahead)
        np.testing.assert_allclose(frames, model.predict(offline(HELLO), fps).values, atol=1e-6)
    # the engine over it: at the server's 30 fps, post-processed, POSTPROCESS_LOOKAHEAD frames later
    stream = open_phone_stream(model, "en")
    assert (stream.fps, stream.lookahead) == (30.0, 1 + POSTPROCESS_LOOKAHEAD)
    frames = push_each(stream, phones_of(HELLO), 30.0, stream.lookahead)
    reference = animate(offline(HELLO), model).select(stream.channels).values
    assert len(frames) == 30 and np.abs(frames - reference).mean() < 0.02

    model.save(tmp_path / "lowlatency")
    config = ServeConfig(cache=":memory:", stream_model=str(tmp_path / "lowlatency"), rate_limit=0,
                         scale="tracker")  # the model's own frames, to compare with the engine's
    with TestClient(create_app(config)) as served, served.websocket_connect("/api/stream") as ws:
        assert served.get("/api/config").json()["stream_model"] == "tdnn-lowlatency"
        ws.send_json({"type": "phones", "phones": phone_dicts(HELLO), "final": True})
        messages = receive_until_end(ws)
        start = messages[0]
        assert (start["fps"], start["model"], start["lookahead"]) == (30.0, "tdnn-lowlatency", 3)
        assert messages[-1]["n_frames"] == 30
    sent = [row for m in messages if m["type"] == "frames" for row in m["frames"]]
    same = open_phone_stream(model, "en")  # the phones arrived in one message
    first = same.push(phones_of(HELLO))[1]
    np.testing.assert_allclose(sent, np.concatenate([first, same.finish()[1]]), atol=1e-6)


def test_stream_command_times_a_real_server(tmp_path):
    """`vispeech stream` against uvicorn on a loopback port (the real WebSocket stack)."""
    import socket
    import threading
    import time

    import uvicorn
    from click.testing import CliRunner

    from vispeech.cli import main

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    app = create_app(ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", ws_max_size=65536))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        url = f"ws://127.0.0.1:{port}/api/stream"
        result = CliRunner().invoke(main, ["stream", "Hej! Hur mår du?", "--language", "sv", "--url", url])
        assert result.exit_code == 0, result.output
        assert "first frame" in result.output and "frames late" in result.output
        refused = CliRunner().invoke(main, ["stream", "hi", "--language", "xx", "--url", url])
        assert refused.exit_code == 2 and "lang" in refused.output
    finally:
        server.should_exit = True
        thread.join(10)
    gone = CliRunner().invoke(main, ["stream", "hi", "--url", url])
    assert gone.exit_code == 2 and "failed" in gone.output


def test_streams_use_the_shipped_low_latency_network_by_default(tmp_path):
    from fastapi.testclient import TestClient

    with TestClient(create_app(ServeConfig(cache=":memory:", rate_limit=0))) as served:
        assert served.get("/api/config").json()["stream_model"] == "grid-tdnn-lowlatency"
        with served.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "language": "en", "phones": phone_dicts(HELLO[:4])})
            start = ws.receive_json()
            # 2 frames ahead at the network's 60 fps are 1 at 30 fps, and post-processing holds back 2 more
            assert (start["fps"], start["model"], start["lookahead"]) == (30.0, "grid-tdnn-lowlatency", 3)
            first = ws.receive_json()  # phones up to 0.28 s: frames 0..8 known, 0..5 ready
            assert first["type"] == "frames" and first["start_frame"] == 0 and len(first["frames"]) == 6
            ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[4:]), "final": True})
            messages = receive_until_end(ws)
    frames = first["frames"] + [row for m in messages if m["type"] == "frames" for row in m["frames"]]
    assert len(frames) == messages[-1]["n_frames"] == 30
    reference = animate(offline(HELLO), "grid-tdnn-lowlatency").select(start["channels"]).values
    assert np.abs(np.array(frames) - reference).mean() < 0.02


@pytest.mark.parametrize("model_name", ["grid-tdnn-lowlatency", "baseline"])
def test_streams_pushed_together_give_what_each_gives_alone(model_name):
    """push_together (what the server runs for the sessions due in one tick) gives every stream the
    frames it gets pushed alone; a stream whose phones are refused gets its error and is left as it
    was, the others go on."""
    from vispeech.models.registry import load_model
    from vispeech.streaming import open_phone_stream, push_together

    model = load_model(model_name)
    texts = ["My mom made a large map.", "Bin blue at F two now.", "Hello there, how are you?"]
    sequences = [list(speak(t, "en", model=model).phones) for t in texts]
    alone = []
    for phones in sequences:
        stream, rows = open_phone_stream(model, "en"), []
        for phone in phones:
            rows.append(stream.push([phone])[1])
        rows.append(stream.finish()[1])
        alone.append(np.concatenate(rows))
    streams = [open_phone_stream(model, "en") for _ in sequences]
    together = [[] for _ in sequences]
    for k in range(max(len(p) for p in sequences)):
        pushes = [(s, [p[k]]) for s, p in zip(streams, sequences) if k < len(p)]
        if k == 3:
            pushes.append((streams[0], [Phone("AA", 0.0, 0.1)]))  # before the phones already given: refused
        results = push_together(pushes)
        if k == 3:
            assert isinstance(results[-1], VispeechError) and "before the previous one ends" in str(results[-1])
            results = results[:-1]
        for (stream, _), (start, rows) in zip(pushes, results):
            together[streams.index(stream)].append(rows)
    for b, stream in enumerate(streams):
        together[b].append(stream.finish()[1])
        np.testing.assert_allclose(np.concatenate(together[b]), alone[b], atol=1e-6)


def test_the_server_pushes_the_sessions_of_one_tick_together():
    """Phone-stream pushes made at once by several sessions run as one pool job (one network step
    per frame for all of them), each session getting the frames message it gets alone, in its own
    output scale; while that job runs, newer pushes wait for the next one."""
    import asyncio
    import json

    from vispeech.serve.service import SpeechService, scaled

    service = SpeechService(ServeConfig(cache=":memory:", workers=1))
    model = service.models["grid-tdnn-lowlatency"]
    phones = [list(speak(t, "en", model=model).phones) for t in ("My mom made a map.", "Bin blue at F two now.",
                                                                 "Hello there.")]
    scales = [service.scale(name)[1] for name in ("arkit", "tracker", "arkit")]
    assert scales[0] is not None and scales[1] is None

    async def run():
        streams = [open_phone_stream(model, "en") for _ in phones]
        first = await asyncio.gather(*(service.pushes.push(s, p[:6], c, 1.0)
                                       for s, p, c in zip(streams, phones, scales)))
        assert (service.pushes.batches, service.pushes.pushes, service.pushes.largest) == (1, 3, 3)
        second = [asyncio.ensure_future(service.pushes.push(s, p[6:9], c, 1.0))
                  for s, p, c in zip(streams, phones, scales)]
        await asyncio.sleep(0)  # the second batch is under way...
        late = asyncio.ensure_future(service.pushes.push(streams[0], phones[0][9:10], scales[0], 1.0))  # ...waits
        await asyncio.gather(*second, late)
        assert service.pushes.batches == 3 and service.pushes.largest == 3
        return first

    first = asyncio.run(run())
    for rows, p, scale in zip(first, phones, scales):
        alone = open_phone_stream(model, "en")
        start, expected = alone.push(p[:6])
        got = json.loads(rows)
        assert got["start_frame"] == start
        np.testing.assert_allclose(got["frames"], scaled(expected, alone, scale).round(6), atol=2e-6)
    service.pool.close()


def test_a_text_message_sets_its_voice_frame_rate_and_scale(client):
    def spoken(**options) -> tuple[dict, bytes]:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "text", "text": "Hello there.", **options})
            messages = receive_until_end(ws)
        audio = b"".join(base64.b64decode(m["pcm16"]) for m in messages if m["type"] == "audio")
        return messages[0], audio

    plain, plain_audio = spoken()
    start, audio = spoken(voice="f3", fps=60, scale="tracker")
    assert (plain["fps"], start["fps"]) == (30.0, 60.0) and audio != plain_audio
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": "Hello there.", "vioce": "f3"})
        error = ws.receive_json()
    assert error["type"] == "error" and "vioce" in error["message"]


def test_a_chat_message_speaks_the_rule_bots_reply_in_its_language(client):
    """A stream chat message with the rule bot: the reply in the message's language, a reply
    message before its audio, and a session to go on in (an unknown one refused, the stream open)."""
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "chat", "message": "Vad heter du?", "language": "en"})
        messages = receive_until_end(ws)
        kinds = [m["type"] for m in messages]
        assert kinds[:2] == ["start", "reply"] and kinds[-1] == "end" and "audio" in kinds
        reply = messages[1]
        assert (reply["text"], reply["language"], reply["start"]) == ("Jag heter Vera.", "sv", 0.0)
        ws.send_json({"type": "chat", "message": "Thanks!", "language": "en", "session": reply["session"]})
        assert [m["text"] for m in receive_until_end(ws) if m["type"] == "reply"] == ["You're welcome!"]
        ws.send_json({"type": "chat", "message": "Hi", "session": "gone"})
        assert "unknown or expired chat session" in receive_until_end(ws)[-1]["message"]
        ws.send_json({"type": "talk", "message": "Hi"})
        assert '"text" or "chat" or "phones"' in ws.receive_json()["message"]


def test_a_phones_stream_sets_its_frame_rate_and_scale(client):
    """A phone stream's first message sets its frame rate (frames 1/fps s apart) and output scale
    (the server's: arkit); a later message may repeat them, not change them."""
    from vispeech.motion.rigging.calibration import load_scale
    from vispeech.motion.track import Track

    def streamed(**options) -> tuple[dict, dict, np.ndarray]:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[:5]), **options})
            start = ws.receive_json()
            ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[5:]), "final": True, **options})
            messages = receive_until_end(ws)
        return start, messages[-1], np.array([row for m in messages if m["type"] == "frames" for row in m["frames"]])

    start, end, plain = streamed()
    fast_start, fast_end, fast = streamed(fps=60)
    assert (start["fps"], end["n_frames"], len(plain)) == (30.0, 30, 30)
    assert (fast_start["fps"], fast_end["n_frames"], len(fast)) == (60.0, 60, 60)
    reference = animate(offline(HELLO), "baseline", 60.0).select(fast_start["channels"]).values
    assert np.abs(fast - load_scale("arkit").apply(Track(reference, fast_start["channels"], 60.0)).values).mean() < 0.02
    _, _, tracker = streamed(scale="tracker")
    channels = tuple(start["channels"])
    np.testing.assert_allclose(plain, load_scale("arkit").apply(Track(tracker, channels, 30.0)).values, atol=2e-6)
    jaw = channels.index("jawOpen")
    assert plain[:, jaw].max() > tracker[:, jaw].max() + 0.05  # not the server's scale
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[:5]), "fps": 60})
        assert ws.receive_json()["fps"] == 60.0
        ws.receive_json()  # its frames
        for change, words in (({"fps": 30}, "fps"), ({"scale": "tracker"}, "scale"), ({"language": "sv"}, "language"),
                              ({"model": "grid-cohen-massaro"}, "model")):
            ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[5:6]), **change})
            error = ws.receive_json()
            assert error["type"] == "error" and f"stream's {words} was set by its first message" in error["message"]
        ws.send_json({"type": "phones", "phones": phone_dicts(HELLO[5:]), "fps": 60, "scale": "arkit", "final": True})
        assert receive_until_end(ws)[-1] == {"type": "end", "n_frames": 60, "duration": 1.0}


def stream_track(messages: list[dict]) -> tuple[list[str], np.ndarray]:
    """The channels and frames (rows) of a stream's messages."""
    rows = [row for m in messages if m["type"] == "frames" for row in m["frames"]]
    return messages[0]["channels"], np.array(rows)


def test_a_text_stream_adds_the_life_layers_asked_for_across_its_clauses(client):
    """Blinks and gaze go on across clauses as over one track (what nonverbal draws over the whole
    timeline, the same for the same seed), and the breath, which a later clause replans, without a
    jump; the speech channels come first, as without the layers. (A stream's espeak-ng runs in its
    fast mode, which may time two runs of a text a little apart: only the phone-free layers are
    compared between runs.)"""
    from vispeech.motion.life import LifePlan, nonverbal

    text = "Hello there, my friend. How are you today? I hope that you are well."

    def spoken(**options) -> tuple[list[str], np.ndarray]:
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"type": "text", "text": text, **options})
            return stream_track(receive_until_end(ws))

    plain_channels, _ = spoken()
    channels, rows = spoken(life=["blink", "gaze", "breath"], seed=3)
    life = LifePlan(("blink", "gaze", "breath"), 30.0).channels
    assert channels == plain_channels + list(life) and channels[: len(STREAM_CHANNELS)] == list(STREAM_CHANNELS)
    assert rows[:, channels.index("jawOpen")].max() > 0.1  # the speech is there
    whole = nonverbal(len(rows), 30.0, layers=("blink", "gaze"), seed=3)
    columns = [channels.index(name) for name in whole.channels]
    np.testing.assert_allclose(rows[:, columns], whole.values, atol=1e-6)
    assert rows[:, channels.index("eyeBlinkLeft")].max() > 0.9  # it blinked (about 17 times a minute)
    breath = rows[:, channels.index("breath")]
    assert breath.max() > 0.4 and np.abs(np.diff(breath)).max() < 0.1  # a breath for speech, no jump
    _, other = spoken(life=["blink", "gaze"], seed=4)
    n = min(len(other), len(rows))
    assert not np.allclose(other[:n, -len(columns) :], rows[:n, columns])  # another seed, other blinks
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": text, "life": ["wink"]})
        error = ws.receive_json()
    assert error["type"] == "error" and error["message"].startswith("life.0:")  # the layers it takes follow
