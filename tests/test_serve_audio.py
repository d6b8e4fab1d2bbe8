"""Audio in, face out: the live audio engine, ``POST /api/animate``, the ``/api/listen`` WebSocket
and ``vispeech stream --audio``, with a tiny audio network trained on GRID (``tiny_audio_model``)."""

from __future__ import annotations

import io
import json
import time
from dataclasses import replace

import numpy as np
import pytest
from conftest import SHARED, require, require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
import soundfile  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from vispeech.errors import VispeechError  # noqa: E402
from vispeech.frontends.audio import AudioClip, to_pcm16  # noqa: E402
from vispeech.models.registry import create_model, load_model  # noqa: E402
from vispeech.pipeline import animate_audio  # noqa: E402
from vispeech.postprocess import PostprocessConfig  # noqa: E402
from vispeech.serve import ServeConfig, create_app  # noqa: E402
from vispeech.guards import TokenBucket  # noqa: E402
from vispeech.streaming import STREAM_CHANNELS, LiveAudioStream  # noqa: E402

CLIP = "bbaf2n"
"""A GRID speaker-1 utterance: "bin blue at f two now", 2.978 s at 16 kHz."""
CHUNK_BYTES = 8192
"""The test server's ``max_chunk_bytes``."""


@pytest.fixture(autouse=True)
def without_voice_activity(monkeypatch):
    """Live streams here rest nowhere, so that their frames equal offline animation's without
    the rest (:func:`live_offline`); the rest on voice activity is tested in test_vad.py."""
    monkeypatch.setattr("vispeech.frontends.vad.SAMPLE_RATE", 0)  # a detector for no network's rate: none


@pytest.fixture(scope="module")
def model(tiny_audio_model):
    return load_model(tiny_audio_model)


@pytest.fixture(scope="module")
def pcm() -> np.ndarray:
    """:data:`CLIP` as 16-bit samples at 16 kHz."""
    path = SHARED / "data" / "grid_s1" / "utterances" / f"{CLIP}.flac"
    require(path.is_file(), f"GRID speaker 1 ({path})")
    samples, rate = soundfile.read(path, dtype="int16")
    assert rate == 16000
    return samples


@pytest.fixture(scope="module")
def clip(pcm) -> AudioClip:
    return AudioClip.from_array(pcm, 16000)


def live_offline(clip: AudioClip, model, fps: float):
    """:func:`animate_audio` of the whole clip as the live stream gives it: the model's preset
    without the mouth at rest in silence, which needs the whole audio's loudness."""
    config = replace(PostprocessConfig.from_preset(model.postprocessing), rest=False)
    return animate_audio(clip, model, fps, postprocessing=config)


def encoded(pcm: np.ndarray, fmt: str, rate: int = 16000) -> bytes:
    buffer = io.BytesIO()
    soundfile.write(buffer, pcm, rate, format=fmt)
    return buffer.getvalue()


@pytest.fixture(scope="module")
def client(tiny_audio_model, tmp_path_factory):
    config = ServeConfig(cache=tmp_path_factory.mktemp("audio") / "cache.sqlite3", rate_limit=0,
                         audio_model=str(tiny_audio_model), upload_model=str(tiny_audio_model),
                         max_audio_bytes=2 * 1024 * 1024,
                         max_chunk_bytes=CHUNK_BYTES, max_stream_seconds=5.0,
                         scale="tracker")  # frames in the model's scale, compared with the library's
    with TestClient(create_app(config)) as client:
        yield client


def receive_until_end(ws) -> list[dict]:
    messages = []
    while True:
        messages.append(ws.receive_json())
        if messages[-1]["type"] in ("end", "error"):
            return messages


def frames_of(messages: list[dict]) -> np.ndarray:
    rows, expected = [], 0
    for m in messages:
        if m["type"] == "frames":
            assert m["start_frame"] == expected
            rows += m["frames"]
            expected += len(m["frames"])
    return np.array(rows)


def random_chunks(data: bytes, rng: np.random.Generator, largest: int = CHUNK_BYTES) -> list[bytes]:
    """``data`` cut into chunks of random even sizes, 2 bytes to ``largest``."""
    chunks, a = [], 0
    while a < len(data):
        n = 2 * int(rng.integers(1, largest // 2 + 1))
        chunks.append(data[a:a + n])
        a += n
    return chunks


# -- the engine ---------------------------------------------------------------------------------

def test_live_audio_stream_equals_the_offline_animation(model, pcm, clip):
    stream = LiveAudioStream(model, 16000, 30.0)
    assert (stream.delay, stream.lookahead) == (model.delay, 6)
    assert stream.channels == STREAM_CHANNELS + tuple(c for c in model.channels if c not in STREAM_CHANNELS)
    reference = live_offline(clip, model, 30.0).select(stream.channels).values  # model.predict, the audio preset
    parts = []
    for chunk in random_chunks(pcm.tobytes(), np.random.default_rng(0)):
        start, rows = stream.push(chunk)
        assert start == sum(len(p) for p in parts)
        # each frame comes once the audio covers its time plus the delay, and not before
        assert (stream.emitted - 1) / 30 + stream.delay <= stream.duration + 1e-6
        assert stream.emitted >= (stream.duration - stream.delay) * 30 - 2
        parts.append(rows)
    parts.append(stream.finish()[1])
    np.testing.assert_allclose(np.concatenate(parts), reference, atol=1e-4)
    jaw = model.channels.index("jawOpen")  # the raw frame, clipped (the preset clamps mouthClose to it)
    np.testing.assert_allclose(np.clip(model.predict(clip, 30.0).values[:, jaw], 0, 1),
                               reference[:, stream.channels.index("jawOpen")], atol=1e-4)
    with pytest.raises(VispeechError, match="ended"):
        stream.push(b"\x00\x00")


def test_live_audio_stream_refuses_what_it_cannot_take(model):
    with pytest.raises(VispeechError, match="animates phones"):
        LiveAudioStream(create_model("baseline"), 16000)
    with pytest.raises(VispeechError, match="sample rate"):
        LiveAudioStream(model, 100)
    with pytest.raises(VispeechError, match="fps"):
        LiveAudioStream(model, 16000, 0.0)
    with pytest.raises(VispeechError, match="cut short"):
        LiveAudioStream(model, 16000).push(b"\x00\x00\x00")


def test_live_audio_streams_pushed_together_give_what_each_gives_alone(model, pcm, monkeypatch):
    """push_audio_together (what the server runs for the listen sessions of one tick) gives every
    stream the frames it gets pushed alone, whatever its chunks, frame rate and start, the new
    frames of all of them post-processed in one call; a stream whose chunk is refused gets its
    error and is left as it was, the others go on."""
    from vispeech import streaming
    from vispeech.streaming import push_audio_together

    postprocess, calls = streaming.postprocess, []
    monkeypatch.setattr(streaming, "postprocess", lambda *args: calls.append(1) or postprocess(*args))

    rng = np.random.default_rng(5)
    audio = [pcm.tobytes(), pcm[: len(pcm) // 2].tobytes(), pcm[::-1].tobytes()]
    plans = [random_chunks(data, rng, 3000) for data in audio]
    starts, rates = [0, 7, 3], [30.0, 60.0, 30.0]
    alone = []
    for chunks, fps in zip(plans, rates):
        stream = LiveAudioStream(model, 16000, fps)
        alone.append(np.concatenate([*(stream.push(chunk)[1] for chunk in chunks), stream.finish()[1]]))
    streams = [LiveAudioStream(model, 16000, fps) for fps in rates]
    together = [[] for _ in streams]
    for tick in range(max(start + len(chunks) for start, chunks in zip(starts, plans))):
        due = [k for k, (start, chunks) in enumerate(zip(starts, plans)) if start <= tick < start + len(chunks)]
        pushes = [(streams[k], plans[k][tick - starts[k]]) for k in due]
        if tick == 10:
            pushes.append((streams[0], b"\x00\x00\x00"))  # cut short: refused
        calls.clear()
        results = push_audio_together(pushes)
        assert len(calls) <= 1
        if tick == 10:
            assert isinstance(results[-1], VispeechError) and "cut short" in str(results[-1])
            results = results[:-1]
        for k, (start, rows) in zip(due, results):
            assert start == sum(len(r) for r in together[k])
            together[k].append(rows)
    for k, stream in enumerate(streams):
        np.testing.assert_allclose(np.concatenate([*together[k], stream.finish()[1]]), alone[k], atol=1e-6)


def test_the_server_pushes_the_listen_sessions_of_one_tick_together(tiny_audio_model, model, pcm):
    """Live audio pushes made at once by several sessions run as one pool job of the kind
    "listen", each session getting the frames message it gets alone, in its own output scale;
    while that job runs, newer pushes wait for the next one; a refused chunk is its session's error."""
    import asyncio

    from vispeech.serve.service import SpeechService, scaled

    service = SpeechService(ServeConfig(cache=":memory:", workers=1, audio_model=str(tiny_audio_model)))
    scales = [service.scale(name)[1] for name in ("arkit", "tracker", "arkit")]
    data = pcm.tobytes()
    kinds = []
    run = service.pool.run
    service.pool.run = lambda kind, *args, **kwargs: kinds.append(kind) or run(kind, *args, **kwargs)

    async def pushed():
        streams = [LiveAudioStream(model, 16000, 30.0) for _ in scales]
        first = await asyncio.gather(*(service.listens.push(s, data[: 9600 * (k + 1)], c, 0.1)
                                       for k, (s, c) in enumerate(zip(streams, scales))))
        assert (service.listens.batches, service.listens.pushes, service.listens.largest) == (1, 3, 3)
        second = [asyncio.ensure_future(service.listens.push(s, data[28800:32000], c, 0.1))
                  for s, c in zip(streams, scales)]
        await asyncio.sleep(0)  # the second batch is under way...
        late = asyncio.ensure_future(service.listens.push(streams[0], b"\x00" * 3, scales[0], 0.1))  # ...waits
        results = await asyncio.gather(*second, late, return_exceptions=True)
        assert service.listens.batches == 3 and service.listens.largest == 3
        assert isinstance(results[-1], VispeechError) and "cut short" in str(results[-1])
        return first

    first = asyncio.run(pushed())
    assert set(kinds) == {"listen"}
    for k, (text, scale) in enumerate(zip(first, scales)):
        alone = LiveAudioStream(model, 16000, 30.0)
        start, expected = alone.push(data[: 9600 * (k + 1)])
        got = json.loads(text)
        assert got["start_frame"] == start and len(expected)
        np.testing.assert_allclose(got["frames"], scaled(expected, alone, scale).round(6), atol=2e-6)
    service.pool.close()



def test_listen_sessions_answered_join_the_next_batch_with_the_pushes_waiting():
    """The sessions a listen batch answers, back within a few turns of the event loop with the
    chunks that came while it ran (as a connection is: resume, send, take its chunks, push),
    join the next batch together with a push that waited for the first to end, instead of
    making a third batch of their own."""
    import asyncio
    import threading
    from types import SimpleNamespace

    from vispeech.serve.pool import WorkPool
    from vispeech.serve.service import LISTEN_SETTLE_TURNS, PushBatcher

    sizes, running = [], threading.Event()

    def together(pushes):
        sizes.append(len(pushes))
        if len(sizes) == 1:
            running.wait(5)  # the first batch runs until the late push is waiting
        return [(0, np.zeros((0, 1)))] * len(pushes)

    service = SimpleNamespace(pool=WorkPool(1, 16), frames_message=lambda *args: None)
    batcher = PushBatcher(service, "listen", "listen streams", together, LISTEN_SETTLE_TURNS)

    async def session(stream, chunks):
        for _ in range(chunks):
            await batcher.push(stream, b"", None, 0.0)
            for _ in range(3):  # the connection's turns from its answer to its next push
                await asyncio.sleep(0)

    async def busy(done):  # a loop with other work: each turn takes 5 ms, the worker free meanwhile
        while not done.done():
            time.sleep(0.005)
            await asyncio.sleep(0)

    async def sessions():
        answered = [asyncio.ensure_future(session(object(), 2)) for _ in range(3)]
        while not sizes:
            await asyncio.sleep(0.001)
        late = asyncio.ensure_future(batcher.push(object(), b"", None, 0.0))
        await asyncio.sleep(0)
        everyone = asyncio.gather(*answered, late)
        loop_work = asyncio.ensure_future(busy(everyone))
        running.set()
        await everyone
        await loop_work

    asyncio.run(sessions())
    service.pool.close()
    assert sizes == [3, 4]

# -- POST /api/animate --------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", ["WAV", "FLAC", "OGG", "MP3"])
def test_animate_an_uploaded_file(client, pcm, clip, model, fmt):
    data = encoded(pcm, fmt)
    answer = client.post("/api/animate", content=data, headers={"Content-Type": f"audio/{fmt.lower()}"})
    assert answer.status_code == 200, answer.text
    body = answer.json()
    animation = body["animation"]
    assert animation["n_frames"] == len(animation["frames"]) == clip.n_frames(30.0) == 90
    assert animation["fps"] == 30.0 and animation["phones"] is None and body["text"] == "" and not body["cached"]
    if fmt in ("WAV", "FLAC"):  # lossless: the offline animation of the same samples
        np.testing.assert_allclose(animation["frames"], animate_audio(clip, model, 30.0).values, atol=1e-5)
    audio = client.get(body["audio_url"])
    assert audio.status_code == 200 and audio.headers["content-type"] == "audio/wav"
    assert soundfile.info(io.BytesIO(audio.content)).frames == len(pcm)
    again = client.post("/api/animate", content=data)
    assert again.json()["cached"] and again.json()["audio_url"] == body["audio_url"]


def test_a_server_animates_uploads_as_vispeech_animate_does(pcm, clip):
    """With no upload model set, /api/animate takes the model `vispeech animate` takes
    (recording_model: with the whisper extra grid-audio-whisper-ensemble for audio alone in every
    language, grid-audio-whisper blended with the transcript's phones when there is one) and
    answers its frames."""
    from vispeech.frontends.whisper import installed
    from vispeech.pipeline import listen, recording_model

    config = ServeConfig(cache=":memory:", rate_limit=0, scale="tracker", audio_model=None)
    frames = {}
    with TestClient(create_app(config)) as client:
        for text, language in ((None, "en"), ("bin blue at f two now", "en"), (None, "sv")):
            params = {"language": language} | ({} if text is None else {"text": text})
            answer = client.post("/api/animate", params=params, content=encoded(pcm, "FLAC"))
            assert answer.status_code == 200, answer.text
            animation = answer.json()["animation"]
            expected = listen(clip, text, language, fps=30.0).track
            frames[text, language] = animation["frames"]
            np.testing.assert_allclose(animation["frames"], expected.select(animation["channels"]).values, atol=1e-4)
    # the language reaches the choice: Swedish audio alone takes its own model where that differs
    same = recording_model(False, "en") == recording_model(False, "sv")
    assert same == np.allclose(frames[None, "en"], frames[None, "sv"])
    assert same == (installed() and installed("whisper-base"))  # the ensemble of both, in every language


def test_animate_takes_what_curl_data_binary_sends(client, pcm):
    """curl --data-binary @file.flac says application/x-www-form-urlencoded: the body is the file."""
    answer = client.post("/api/animate", content=encoded(pcm, "FLAC"),
                         headers={"Content-Type": "application/x-www-form-urlencoded"})
    assert answer.status_code == 200, answer.text
    assert answer.json()["animation"]["n_frames"] == 90


def test_animate_with_a_transcript_and_another_frame_rate(client, pcm):
    data = encoded(pcm, "FLAC")
    answer = client.post("/api/animate", params={"text": "bin blue at f two now", "fps": 25}, content=data)
    assert answer.status_code == 200, answer.text
    animation = answer.json()["animation"]
    assert animation["fps"] == 25.0 and animation["n_frames"] == 75  # ceil(2.978 * 25)
    words = [w["text"] for w in animation["phones"]["words"]]
    assert words == "bin blue at f two now".split() and answer.json()["text"] == "bin blue at f two now"


def test_a_transcript_that_does_not_fit_is_a_400_unless_forced(client, pcm):
    data, wrong = encoded(pcm, "FLAC"), {"text": "the quick brown fox jumps over the lazy dog"}
    refused = client.post("/api/animate", params=wrong, content=data)
    assert refused.status_code == 400 and "does not fit the audio" in refused.json()["detail"]
    assert "force=true" in refused.json()["detail"]
    forced = client.post("/api/animate", params={**wrong, "force": "true"}, content=data)
    assert forced.status_code == 200 and forced.json()["animation"]["phones"]["words"][0]["text"] == "the"
    assert client.post("/api/animate", params=wrong, content=data).status_code == 400  # not the forced answer


def test_animate_adds_the_non_verbal_layers_asked_for(client, pcm):
    """life and seed, in the query or the form, add their layers to the cached speech's frames."""
    data, text = encoded(pcm, "FLAC"), "bin blue at f two now"
    plain = client.post("/api/animate", params={"text": text}, content=data).json()
    lively = client.post("/api/animate", params={"text": text, "life": ["blink", "head"], "seed": 3}, content=data)
    assert lively.status_code == 200, lively.text
    lively = lively.json()
    assert lively["cached"] and lively["audio_url"] == plain["audio_url"]
    animation, speech = lively["animation"], plain["animation"]
    assert animation["channels"][-5:] == ["eyeBlinkLeft", "eyeBlinkRight", "headYaw", "headPitch", "headRoll"]
    frames = np.array(animation["frames"])
    np.testing.assert_array_equal(frames[:, :len(speech["channels"])], speech["frames"])
    assert np.abs(frames[:, animation["channels"].index("headYaw")]).max() > 0
    form = client.post("/api/animate", files={"file": ("take.flac", data)},
                       data={"text": text, "life": ["blink", "head"], "seed": "3"})
    assert form.status_code == 200 and form.json()["animation"] == animation, form.text


def test_bad_uploads_get_a_clear_4xx(client, pcm):
    good = encoded(pcm, "FLAC")
    long_silence = encoded(np.zeros(601 * 8000, dtype=np.int16), "FLAC", rate=8000)
    for params, body, headers, status, words in [
        ({}, b"", {}, 400, "empty"),
        ({}, b"RIFF this is no audio at all", {"Content-Type": "audio/wav"}, 400, "not an audio file"),
        ({}, long_silence, {}, 400, "the limit is 600 s"),
        ({"fps": 0}, good, {}, 422, "fps"),
        ({"fps": 1000}, good, {}, 422, "fps"),
        ({"fps": "fast"}, good, {}, 422, "fps"),
        ({"model": "nope"}, good, {}, 400, "unknown model"),
        ({"model": "grid-tdnn"}, good, {}, 400, "transcript"),
        ({"text": "bin blue zqxjv"}, good, {}, 400, "not in the pronouncing dictionary"),
        ({"text": ""}, good, {}, 422, "text"),
        ({"vioce": "f3"}, good, {}, 422, "unknown field 'vioce'"),  # never silently ignored
        ({"life": "wink"}, good, {}, 422, "life"),
        ({}, good, {"Content-Type": "application/json"}, 415, "not JSON"),
        ({}, good, {"Content-Type": "multipart/form-data; boundary=x"}, 400, "multipart"),
        ({}, bytes(2 * 1024 * 1024 + 2), {}, 413, "too large"),
    ]:
        answer = client.post("/api/animate", params=params, content=body, headers=headers)
        assert answer.status_code == status and words in answer.json()["detail"], (params, answer.text)
    assert client.get("/api/config").status_code == 200


def test_animate_a_file_sent_as_a_multipart_form(client, pcm):
    """curl -F file=@take.flac -F text=...: the file is the part "file", the fields set the options
    over the query's, and the answer is the one of the same file sent as the body."""
    data = encoded(pcm, "FLAC")
    answer = client.post("/api/animate", params={"fps": 30}, files={"file": ("take.flac", data, "audio/flac")},
                         data={"text": "bin blue at f two now", "fps": "25"})
    assert answer.status_code == 200, answer.text
    animation = answer.json()["animation"]
    assert animation["fps"] == 25.0 and animation["n_frames"] == 75
    assert [w["text"] for w in animation["phones"]["words"]] == "bin blue at f two now".split()
    as_body = client.post("/api/animate", params={"text": "bin blue at f two now", "fps": 25}, content=data)
    assert as_body.json()["cached"] and as_body.json()["animation"] == animation
    plain = client.post("/api/animate", files={"file": ("take.flac", data)})
    assert plain.status_code == 200 and plain.json()["animation"]["phones"] is None
    files = client.post("/api/animate", files={"file": ("take.flac", data)}, data={"formats": ["oculus", "rhubarb"]})
    assert files.status_code == 200 and set(files.json()["files"]) == {"oculus", "rhubarb"}, files.text


def test_bad_multipart_uploads_get_a_clear_4xx(client, pcm):
    good = ("take.flac", encoded(pcm, "FLAC"), "audio/flac")
    for files, fields, status, words in [
        ({"audio": good}, {}, 422, "part 'file'"),
        ({"file": ("take.flac", b"")}, {}, 400, "empty"),
        ({"file": ("take.flac", b"RIFF this is no audio at all")}, {}, 400, "not an audio file"),
        ({"file": good}, {"voice": "f3"}, 422, "unknown field 'voice'"),
        ({"file": good}, {"fps": "fast"}, 422, "fps"),
        ({"file": good}, {"text": ""}, 422, "text"),
        ({"file": good}, {"model": "nope"}, 400, "unknown model"),
        ({"file": good}, {"text": "the quick brown fox jumps over the lazy dog"}, 400, "does not fit the audio"),
        ([("file", good), ("file", good)], {}, 400, "files"),
    ]:
        answer = client.post("/api/animate", files=files, data=fields)
        assert answer.status_code == status and words in answer.json()["detail"], (files, fields, answer.text)


def test_a_multipart_upload_over_the_limit_is_refused_before_it_is_parsed(client, monkeypatch):
    """The audio upload limit (2 MiB in the test server) holds for forms: a form that says its
    length is refused unread, one sent in chunks once it passes the limit."""
    import httpx
    from starlette.requests import Request

    big = httpx.Request("POST", "http://testserver/api/animate",
                        files={"file": ("take.wav", bytes(2 * 1024 * 1024), "audio/wav")})
    body, headers = big.read(), dict(big.headers)

    def parse(*args, **kwargs):
        raise AssertionError("the form was parsed")

    with monkeypatch.context() as patched:
        patched.setattr(Request, "form", parse)
        answer = client.post("/api/animate", content=body, headers=headers)
    assert answer.status_code == 413 and "too large" in answer.json()["detail"]
    del headers["content-length"]
    chunks = (body[k:k + 65536] for k in range(0, len(body), 65536))
    answer = client.post("/api/animate", content=chunks, headers=headers)
    assert answer.status_code == 413 and "too large" in answer.json()["detail"]
    assert client.get("/api/config").status_code == 200


def test_live_audio_needs_an_audio_model(tmp_path, pcm):
    """Without one /api/listen refuses a stream (uploads have theirs: the test above)."""
    config = ServeConfig(cache=":memory:", rate_limit=0, audio_model=None)
    with TestClient(create_app(config)) as bare:
        assert bare.get("/api/config").json()["audio_model"] is None
        with bare.websocket_connect("/api/listen") as ws:
            ws.send_json({"type": "start", "sample_rate": 16000})
            assert "no audio model" in ws.receive_json()["message"]
    with pytest.raises(VispeechError, match="animates phones"):
        create_app(ServeConfig(cache=":memory:", audio_model="grid-tdnn"))


# -- WS /api/listen -----------------------------------------------------------------------------

def test_live_audio_in_random_chunks_gives_the_offline_frames(client, pcm, clip, model):
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000, "encoding": "pcm16"})
        start = ws.receive_json()
        channels = LiveAudioStream(model, 16000).channels
        assert start == {"type": "start", "fps": 30.0, "channels": list(channels), "sample_rate": 16000,
                         "model": client.get("/api/config").json()["audio_model"], "lookahead": 6,
                         "delay": pytest.approx(model.delay)}
        for chunk in random_chunks(pcm.tobytes(), np.random.default_rng(1)):
            ws.send_bytes(chunk)
        ws.send_json({"type": "stop"})
        messages = receive_until_end(ws)
    assert messages[-1] == {"type": "end", "n_frames": 90, "duration": pytest.approx(len(pcm) / 16000)}
    assert "too_fast" in [m["code"] for m in messages if m["type"] == "warning"]  # all of it at once
    np.testing.assert_allclose(frames_of(messages), live_offline(clip, model, 30.0).select(channels).values, atol=1e-4)


def test_every_stream_sends_the_same_channels(client, pcm):
    """A text stream (phones, tongue from them) and a listen stream (audio alone, no tongue) start
    with the same channel list; the listen stream's tongue stays at rest."""
    with client.websocket_connect("/api/stream") as ws:
        ws.send_json({"type": "text", "text": "Hello.", "model": "grid-cohen-massaro"})
        spoken = ws.receive_json()
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000})
        heard = ws.receive_json()
        for chunk in random_chunks(pcm.tobytes(), np.random.default_rng(2)):
            ws.send_bytes(chunk)
        ws.send_json({"type": "stop"})
        frames = frames_of(receive_until_end(ws))
    assert spoken["type"] == heard["type"] == "start" and spoken["channels"] == heard["channels"]
    assert set(spoken["channels"]) >= {"cheekPuff", "tongueTipUp", "jawOpen"}
    tongue = [heard["channels"].index(name) for name in ("tongueOut", "tongueTipUp", "tongueBodyUp", "tongueBack")]
    assert frames.shape[1] == len(heard["channels"]) and not frames[:, tongue].any() and frames.any()


def test_live_audio_at_48_khz_and_25_fps(client, clip, model):
    samples = to_pcm16(clip.resampled(48000).samples)
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 48000, "fps": 25})
        start = ws.receive_json()
        assert (start["sample_rate"], start["fps"]) == (48000, 25.0) and start["delay"] > model.delay
        data = samples.tobytes()
        for a in range(0, len(data), 1920):  # 20 ms chunks
            ws.send_bytes(data[a:a + 1920])
        ws.send_json({"type": "stop"})
        messages = receive_until_end(ws)
    frames = frames_of(messages)
    assert len(frames) == messages[-1]["n_frames"] == clip.n_frames(25.0) == 75
    assert np.abs(frames - live_offline(clip, model, 25.0).select(start["channels"]).values).mean() < 0.01


def test_bad_listen_messages_get_errors_and_the_connection_goes_on(client, pcm):
    with client.websocket_connect("/api/listen") as ws:
        for bad, words in [
            ("not json", "not valid JSON"),
            ('{"type": "text", "text": "hi"}', '"type" must be "start" or "stop"'),
            ('{"sample_rate": 16000}', '"type" is missing: use "start" or "stop"'),
            ('{"type": "start"}', "sample_rate"),
            ('{"type": "start", "sample_rate": 100}', "sample_rate"),
            ('{"type": "start", "sample_rate": 16000, "encoding": "opus"}', "encoding"),
            ('{"type": "start", "sample_rate": 16000, "fps": 0}', "fps"),
            ('{"type": "start", "sample_rate": 16000, "model": "nope"}', "unknown model"),
            ('{"type": "start", "sample_rate": 16000, "model": "baseline"}', "animates phones"),
            ('{"type": "stop"}', "no audio stream is open"),
        ]:
            ws.send_text(bad)
            reply = ws.receive_json()
            assert reply["type"] == "error" and words in reply["message"], (bad, reply)
        # audio before a start: one error, then the chunks are dropped until the next text message
        ws.send_bytes(pcm[:320].tobytes())
        ws.send_bytes(pcm[320:640].tobytes())
        assert "before audio" in ws.receive_json()["message"]
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert "an audio stream is open" in ws.receive_json()["message"]
        # a chunk over the limit ends the stream; what follows is dropped until a text message
        ws.send_bytes(bytes(CHUNK_BYTES + 2))
        ws.send_bytes(bytes(320))
        reply = ws.receive_json()
        assert f"at most {CHUNK_BYTES} bytes" in reply["message"] and "has ended" in reply["message"]
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        ws.send_bytes(bytes(321))
        assert "cut short" in ws.receive_json()["message"]
        # past the stream limit (5 s here)
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        second = bytes(32000)
        for _ in range(6):
            ws.send_bytes(second[:CHUNK_BYTES])
            ws.send_bytes(second[CHUNK_BYTES:2 * CHUNK_BYTES])
            ws.send_bytes(second[2 * CHUNK_BYTES:3 * CHUNK_BYTES])
            ws.send_bytes(second[3 * CHUNK_BYTES:])
        messages = receive_until_end(ws)
        assert "at most 5 s" in messages[-1]["message"] and "has ended" in messages[-1]["message"]
        assert len(frames_of(messages)) <= 150
        ws.send_text("x" * 70_000)
        assert "too large" in ws.receive_json()["message"]


def test_rate_limit_and_a_lagging_server_are_told(client, pcm, monkeypatch):
    service = client.app.state.service
    monkeypatch.setattr(service.config, "max_audio_lag", 0.0)  # every batch is "late"
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        ws.send_bytes(pcm[:1600].tobytes())
        warning = ws.receive_json()  # 0.1 s of audio: no frames yet
        assert warning["type"] == "warning" and warning["code"] == "behind" and warning["seconds"] >= 0
    monkeypatch.setattr(service, "bucket", TokenBucket(0.001, 1))
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        for _ in range(50):  # 5 s of audio: 1.25 tokens, more than the burst
            ws.send_bytes(bytes(3200))
        messages = receive_until_end(ws)
        assert "rate limit" in messages[-1]["message"] and "has ended" in messages[-1]["message"]


def test_a_client_that_goes_away_frees_its_session(client, pcm):
    service = client.app.state.service
    assert service.active_streams == 0
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"
        for a in range(0, 16000, 320):
            ws.send_bytes(pcm[a:a + 320].tobytes())
        assert service.active_streams == 1
    deadline = time.monotonic() + 5
    while (service.active_streams or service.pool.queued or service.pool.running) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert service.active_streams == 0 and service.pool.queued == 0 and service.pool.running == 0
    with client.websocket_connect("/api/listen") as ws:  # the server carries on
        ws.send_json({"type": "start", "sample_rate": 16000})
        assert ws.receive_json()["type"] == "start"


# -- vispeech stream --audio --------------------------------------------------------------------

def test_stream_command_replays_audio_to_a_real_server(tiny_audio_model, pcm, tmp_path):
    """`vispeech stream --audio` against uvicorn on a loopback port (the real WebSocket stack)."""
    import socket
    import threading

    import uvicorn
    from click.testing import CliRunner

    from vispeech.cli import main

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    app = create_app(ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0, audio_model=str(tiny_audio_model),
                                 scale="tracker"))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", ws_max_size=65536))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wav = tmp_path / "one_second.wav"
    soundfile.write(wav, pcm[8000:24000], 16000)  # 1 s from the middle of the utterance
    flac = tmp_path / "utterance.flac"
    soundfile.write(flac, pcm, 16000)
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        url = f"ws://127.0.0.1:{port}/api/listen"
        out = tmp_path / "frames.json"
        fast = CliRunner().invoke(main, ["stream", "--audio", str(flac), "--fast", "--url", url, "--out", str(out)])
        assert fast.exit_code == 0, fast.output
        assert "90 at 30 fps" in fast.output and "frame delay" in fast.output and "faster than" in fast.output
        written = json.loads(out.read_text())
        assert written["n_frames"] == 90 and len(written["frames"]) == 90
        address = f"http://127.0.0.1:{port}"  # the server's address, as a browser has it: /api/listen added
        paced = CliRunner().invoke(main, ["stream", "--audio", str(wav), "--url", address, "--fps", "25"])
        assert paced.exit_code == 0, paced.output
        assert "25 at 25 fps" in paced.output and "in real time" in paced.output and "frame delay" in paced.output
        refused = CliRunner().invoke(main, ["stream", "--audio", str(wav), "--url", url, "--model", "baseline"])
        assert refused.exit_code == 2 and "animates phones" in refused.output
        both = CliRunner().invoke(main, ["stream", "hello", "--audio", str(wav), "--url", url])
        assert both.exit_code == 2 and "not both" in both.output
    finally:
        server.should_exit = True
        thread.join(10)


def test_a_listen_stream_sets_its_output_scale(client, pcm, clip, model):
    """A start with "scale" gets its frames, and a cancel's, in that scale instead of the server's
    (tracker here)."""
    from vispeech.motion.rigging.calibration import load_scale
    from vispeech.motion.track import Track
    from vispeech.postprocess.rest import rest_ease

    arkit = load_scale("arkit")
    with client.websocket_connect("/api/listen") as ws:
        ws.send_json({"type": "start", "sample_rate": 16000, "scale": "arkit"})
        start = ws.receive_json()
        for chunk in random_chunks(pcm.tobytes(), np.random.default_rng(3)):
            ws.send_bytes(chunk)
        ws.send_json({"type": "stop"})
        frames = frames_of(receive_until_end(ws))
        ws.send_json({"type": "cancel"})
        cancelled = ws.receive_json()
    channels = tuple(start["channels"])
    raw = live_offline(clip, model, 30.0).select(channels)
    np.testing.assert_allclose(frames, arkit.apply(raw).values, atol=1e-4)
    jaw = channels.index("jawOpen")
    assert frames[:, jaw].max() > raw.values[:, jaw].max() + 0.05  # not the server's scale
    eased = arkit.apply(Track(rest_ease(raw.values[-1], 30.0), channels, 30.0)).values
    np.testing.assert_allclose(cancelled["frames"], eased, atol=1e-4)


def test_a_server_refuses_an_audio_model_that_cannot_stream_live_audio():
    """--audio-model names the model of /api/listen: an ensemble animates whole recordings only,
    so a server given one stops at start with a one-line reason."""
    from vispeech.serve.service import SpeechService

    with pytest.raises(VispeechError, match="the audio model must stream live audio: .*does not stream"):
        SpeechService(ServeConfig(cache=":memory:", workers=1, audio_model="grid-audio-whisper-ensemble"))
