"""Realtime voice services through ``/api/listen``: the example clients of ``examples/realtime``
relay their recorded fixtures (PCM; PCM + character timings; PCM + word timings or visemes) to
the server in-process, barge-in, and bad messages."""

from __future__ import annotations

import importlib.util
import json
import math
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402

from vispeech.alignment.phones import Word  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.frontends.timings import characters_to_words, phones_over_visemes, timed_word_phones  # noqa: E402
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture  # noqa: E402
from vispeech.motion.track import Track  # noqa: E402
from vispeech.pipeline import animate, animate_audio  # noqa: E402
from vispeech.postprocess import PostprocessConfig  # noqa: E402
from vispeech.realtime import TimedSpeechStream  # noqa: E402
from vispeech.serve import ServeConfig, create_app  # noqa: E402
from vispeech.serve.listen import ListenConnection  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "realtime" / "relay.py"
spec = importlib.util.spec_from_file_location("relay", EXAMPLE)
assert spec is not None and spec.loader is not None
relay = importlib.util.module_from_spec(spec)
spec.loader.exec_module(relay)

BILABIALS = ("P", "B", "M")
TICKS = relay.TICKS


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    config = ServeConfig(cache=tmp_path_factory.mktemp("realtime") / "cache.sqlite3", rate_limit=0,
                         scale="tracker")  # frames in the models' scale, compared with the library's
    with TestClient(create_app(config)) as client:
        yield client


def answers_of(ws, messages) -> list[dict]:
    """Send ``messages`` and receive up to the stream's ``end`` (or ``cancelled``); no errors."""
    for message in messages:
        (ws.send_bytes if isinstance(message, bytes) else ws.send_text)(message)
    answers = [ws.receive_json()]
    while answers[-1]["type"] not in ("end", "cancelled"):
        answers.append(ws.receive_json())
        assert answers[-1]["type"] != "error", answers[-1]
    return answers


def relayed(client, service: str) -> tuple[dict, np.ndarray, dict]:
    with client.websocket_connect("/api/listen") as ws:
        answers = answers_of(ws, relay.messages_for(service))
    return answers[0], relay.frames_of(answers), answers[-1]


def fixture_audio() -> AudioClip:
    events, rate = relay.read_fixture("openai")
    pcm = b"".join(m for m in relay.openai_messages(events, rate) if isinstance(m, bytes))
    return AudioClip.from_array(np.frombuffer(pcm, "<i2"), rate)


def fixture_words(service: str) -> list[Word]:
    """The words the fixture's timings give, as the server reads them."""
    events, _ = relay.read_fixture(service)
    if service == "elevenlabs":
        chars = [c for e in events if e["alignment"] for c in zip(*e["alignment"].values())]
        return characters_to_words(*map(list, zip(*chars)))
    return [Word(e["text"], e["audio_offset"] / TICKS, (e["audio_offset"] + e["duration"]) / TICKS)
            for e in events if e["event"] == "WordBoundary"]


def closures(frames: np.ndarray, channels, phones, fps: float) -> list[float]:
    """The least lip aperture in (a frame around) each /p b m/ of ``phones``."""
    aperture = lip_aperture(Track(frames, tuple(channels), fps))
    return [float(aperture[max(0, int(p.start * fps) - 1):math.ceil(p.end * fps) + 1].min())
            for p in phones if p.symbol in BILABIALS]


def test_a_pcm_stream_is_animated_by_the_audio_model(client):
    begin, frames, end = relayed(client, "openai")
    clip = fixture_audio()
    assert begin["model"] == "grid-audio-cnn" and begin["delay"] > 0
    assert end["duration"] == pytest.approx(clip.duration) and len(frames) == end["n_frames"] == clip.n_frames(30.0)
    config = replace(PostprocessConfig.from_preset("audio"), rest=False)  # live audio rests by its own VAD
    reference = animate_audio(clip, "grid-audio-cnn", 30.0, postprocessing=config).select(begin["channels"]).values
    jaw = begin["channels"].index("jawOpen")
    words = fixture_words("azure")
    speech = slice(math.ceil(words[0].start * 30), math.floor(words[-1].end * 30))
    assert np.abs(frames[speech, jaw] - reference[speech, jaw]).max() < 0.02


@pytest.mark.parametrize("service", ["elevenlabs", "azure"])
def test_timed_streams_give_the_offline_frames_and_close_the_lips(client, service):
    begin, frames, end = relayed(client, service)
    assert begin["model"] == "grid-tdnn-lowlatency" and begin["delay"] is None
    phones = timed_word_phones(fixture_words(service), "en", end["duration"])
    reference = animate(phones, "grid-tdnn-lowlatency").select(begin["channels"]).values
    assert frames.shape == reference.shape and end["n_frames"] == len(frames)
    jaw = begin["channels"].index("jawOpen")
    assert np.abs(frames[:, jaw] - reference[:, jaw]).max() < 0.02
    closed = closures(frames, begin["channels"], phones, begin["fps"])
    assert len(closed) == 7 and max(closed) <= LIP_CLOSED


def test_visemes_close_the_lips_on_their_bilabials(client):
    begin, frames, end = relayed(client, "azure-visemes")
    events, _ = relay.read_fixture("azure")
    visemes = [(e["viseme_id"], e["audio_offset"] / TICKS) for e in events if e["event"] == "VisemeReceived"]
    phones = phones_over_visemes(visemes, end["duration"])
    assert len(frames) == end["n_frames"] == math.ceil(end["duration"] * begin["fps"] - 1e-9)
    closed = closures(frames, begin["channels"], phones, begin["fps"])
    assert len(closed) == 7 and max(closed) <= LIP_CLOSED
    assert lip_aperture(Track(frames, tuple(begin["channels"]), begin["fps"])).max() > 0.1  # and it opens


@pytest.mark.parametrize("service", ["azure", "openai"])
def test_barge_in_rests_the_mouth_and_the_next_utterance_goes_on(client, service):
    messages = list(relay.messages_for(service))
    alone = relayed(client, service)[1]
    with client.websocket_connect("/api/listen") as ws:
        half = [m for m in messages[:len(messages) // 2]]
        answers = answers_of(ws, [*half, json.dumps({"type": "cancel"})])
        cancelled = answers[-1]
        assert cancelled["type"] == "cancelled" and len(cancelled["frames"]) == 3
        frames = relay.frames_of(answers[1:])
        assert cancelled["n_frames"] == len(frames) and not np.any(frames[-1])  # the mouth at rest
        jaw = answers[0]["channels"].index("jawOpen")
        assert np.all(np.diff(frames[-4:, jaw]) <= 0)  # eased there from the last frame sent
        # the next utterance: a stream of its own from frame 0, as if alone
        answers = answers_of(ws, messages)
        assert answers[0]["type"] == "start" and answers[1]["start_frame"] == 0
        assert np.allclose(relay.frames_of(answers), alone, atol=1e-6)
        # the usual barge-in: the service has sent it all, the client plays frame 20 of it
        ws.send_text(json.dumps({"type": "cancel", "frame": 20}))
        cancelled = ws.receive_json()
        assert cancelled["type"] == "cancelled" and cancelled["start_frame"] == 21 and cancelled["n_frames"] == 24
        ease = np.array(cancelled["frames"])
        assert np.allclose(ease[0] / ease[0, jaw], alone[20] / alone[20, jaw], atol=1e-5) and not ease[-1].any()
        # nothing left to cancel: an answer without frames
        ws.send_text(json.dumps({"type": "cancel"}))
        assert ws.receive_json() == {"type": "cancelled", "start_frame": 0, "frames": [], "n_frames": 0,
                                     "duration": 0.0}


@pytest.mark.parametrize("cancel", [{"type": "cancel"}, {"type": "cancel", "frame": None},
                                    {"type": "cancel", "frame": 10_000}])  # a frame past the last sent: from it
def test_a_cancel_drops_the_audio_and_timings_waiting_before_it(client, monkeypatch, cancel):
    """While the first words are worked on, the reader reads the rest and the cancel (within the
    2 s of audio it lets wait): the words and audio waiting before the cancel are dropped unworked.
    The first words are worked until the cancel has been read, whatever the machine's load. A
    cancel with its frame is a cancel all the same."""
    worked, working, cancel_read = [], threading.Event(), threading.Event()
    add_words, enqueue = TimedSpeechStream.add_words, ListenConnection._enqueue

    def held_add_words(stream, words):
        worked.append([w.text for w in words])
        working.set()
        assert cancel_read.wait(10)
        return add_words(stream, words)

    async def spied_enqueue(connection, event):
        await enqueue(connection, event)
        if event["epoch"]:  # the cancel is in the inbox
            cancel_read.set()

    monkeypatch.setattr(TimedSpeechStream, "add_words", held_add_words)
    monkeypatch.setattr(ListenConnection, "_enqueue", spied_enqueue)
    messages = list(relay.messages_for("azure"))
    first = next(k for k, m in enumerate(messages) if isinstance(m, str) and '"type": "words"' in m)
    assert [type(m) for m in messages[:first]] == [str, bytes]  # the start, 0.2 s of audio, then "Please"
    with client.websocket_connect("/api/listen") as ws:
        for message in messages[:first + 1]:
            (ws.send_bytes if isinstance(message, bytes) else ws.send_text)(message)
        assert working.wait(10)
        answers = answers_of(ws, [*messages[first + 1:len(messages) * 2 // 3], json.dumps(cancel)])
    assert worked == [["Please"]]
    assert [a["type"] for a in answers] == ["start", "frames", "cancelled"]
    assert answers[2]["start_frame"] == len(answers[1]["frames"])
    assert answers[2]["duration"] == 0.2  # the audio after the first words was dropped uncounted


def test_bad_messages_get_one_error_each_and_the_stream_goes_on(client):
    messages = list(relay.messages_for("azure"))
    with client.websocket_connect("/api/listen") as ws:
        for bad, words in [
            ({"type": "words", "words": []}, "no audio stream is open"),
            ({"type": "start", "sample_rate": 16000, "timings": "phones"}, "timings"),
            ({"type": "start", "sample_rate": 16000, "timings": "words", "model": "grid-audio-cnn"},
             "timings need a model that animates phones"),
            ({"type": "start", "sample_rate": 16000, "timings": "words", "language": "xx"}, "language"),
            ({"type": "cancle"}, '"type" must be "start" or "stop" or "cancel"'),
        ]:
            ws.send_text(json.dumps(bad))
            reply = ws.receive_json()
            assert reply["type"] == "error" and words in reply["message"], (bad, reply)
        ws.send_text(messages[0])
        assert ws.receive_json()["type"] == "start"
        word = {"text": "map", "start": 0.3, "end": 0.6}
        for bad, words in [
            ({"type": "characters", "characters": ["a"], "character_start_times_seconds": [0.0],
              "character_end_times_seconds": [0.1]}, "takes words, not characters"),
            ({"type": "characters", "characters": ["a", "b"], "character_start_times_seconds": [0.0],
              "character_end_times_seconds": [0.1]}, "must be as many"),
            ({"type": "words", "words": [{**word, "end": 0.2}]}, "ends (0.2) before it starts"),
            ({"type": "words", "words": [{**word, "speaker": 1}]}, "unknown field 'words.0.speaker'"),
            ({"type": "words", "words": [{**word, "end": 700.0}]}, "less than or equal to 600"),
            ({"type": "words", "words": [{**word, "end": 25.0}]}, "may add at most 20 s (this one adds 25.0 s)"),
            ({"type": "words", "words": [word], "extra": True}, "unknown field 'extra'"),
            ({"type": "visemes", "visemes": [{"viseme": 22, "time": 0.1}]}, "less than or equal to 21"),
            ({"type": "visemes", "visemes": [{"viseme": "XX", "time": 0.1}]}, "unknown viseme"),
            ({"type": "visemes", "visemes": [{"viseme": 21, "time": 0.1}]}, "takes words, not visemes"),
            ({"type": "start", "sample_rate": 16000}, "an audio stream is open"),
        ]:
            ws.send_text(json.dumps(bad))
            reply = ws.receive_json()
            assert reply["type"] == "error" and words in reply["message"], (bad, reply)
        answers = answers_of(ws, messages[1:])
        assert relay.frames_of([{"type": "start"}, *answers]).shape[0] == answers[-1]["n_frames"]
        # a word that ends before the words sent end is refused whole; the stream goes on
        ws.send_text(messages[0])
        assert ws.receive_json()["type"] == "start"
        ws.send_text(json.dumps({"type": "words", "words": [{"text": "bring", "start": 0.5, "end": 0.8}]}))
        assert ws.receive_json()["type"] == "frames"
        ws.send_text(json.dumps({"type": "words", "words": [word]}))
        assert "before the words before it end" in ws.receive_json()["message"]
        answers = answers_of(ws, [json.dumps({"type": "stop"})])
        assert answers[-1]["type"] == "end" and answers[-1]["n_frames"] == math.ceil(0.8 * 30)
    with client.websocket_connect("/api/listen") as ws:  # timings for a stream of audio alone
        ws.send_text(json.dumps({"type": "start", "sample_rate": 16000}))
        assert ws.receive_json()["type"] == "start"
        ws.send_text(json.dumps({"type": "words", "words": [word]}))
        assert "takes no timings" in ws.receive_json()["message"]


def test_the_example_clients_relay_to_a_real_server(client, tmp_path, monkeypatch, capsys):
    """``examples/realtime/relay.py`` over uvicorn on a loopback port (the real WebSocket stack):
    the frames the in-process server gives."""
    import asyncio
    import socket
    import sys
    import threading

    import uvicorn

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    app = create_app(ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0, scale="tracker"))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", ws_max_size=65536))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"ws://127.0.0.1:{port}/api/listen"
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        for service in ("openai", "elevenlabs"):
            answers = asyncio.run(relay.relay(url, relay.messages_for(service)))
            assert np.allclose(relay.frames_of(answers), relayed(client, service)[1], atol=1e-6)
        out = tmp_path / "frames.json"
        monkeypatch.setattr(sys, "argv", ["relay.py", "azure", "--url", url, "--out", str(out)])
        relay.main()
        assert "azure: 68 frames at 30 fps from grid-tdnn-lowlatency, 2.25 s of audio" in capsys.readouterr().out
        written = json.loads(out.read_text())
        assert np.allclose(written["frames"], relayed(client, "azure")[1], atol=1e-6)
    finally:
        server.should_exit = True
        thread.join(10)


def test_timings_after_a_long_pause_in_the_audio_are_taken(client):
    """A message may add 20 s of frames past what the timings and the audio already reach: after
    25 s of audio with no word, the next word (at 24 s) is taken, not refused as 24 s added."""
    with client.websocket_connect("/api/listen") as ws:
        ws.send_text(json.dumps({"type": "start", "sample_rate": 16000, "timings": "words"}))
        assert ws.receive_json()["type"] == "start"
        for _ in range(25):  # a second of silence each
            ws.send_bytes(bytes(32000))
        answers = answers_of(ws, [json.dumps({"type": "words", "words": [{"text": "map", "start": 24.0, "end": 24.4}]}),
                                  json.dumps({"type": "stop"})])
    kinds = [a["type"] for a in answers if a["type"] != "warning"]  # 25 s sent at once: too fast, says the server
    assert kinds[0] == "frames" and kinds[-1] == "end"
