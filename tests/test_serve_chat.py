"""Chat with a chat model: the OpenAI-compatible adapter against a local fake server that streams,
the reply spoken clause by clause as it arrives (each sentence in its own language), the sessions'
history and its bounds, and the upstream's failures."""

from __future__ import annotations

import base64
import json
import logging
import threading
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402

from vispeech.errors import VispeechError  # noqa: E402
from vispeech.frontends.espeak import synthesize  # noqa: E402
from vispeech.serve import ServeConfig, create_app  # noqa: E402
from vispeech.serve.bot import ChatTurn  # noqa: E402
from vispeech.serve.chat import ReplyReader  # noqa: E402
from vispeech.serve.llm import OpenAIChatBot, completions_url  # noqa: E402
from vispeech.serve.sessions import ChatSessions, UnknownSession  # noqa: E402

KEY = "sk-test-0123456789abcdef"
SYSTEM = "You are Vera, a friendly avatar. Answer briefly."


def chunk(content: str | None = None, finish: str | None = None) -> str:
    delta = {} if content is None else {"content": content}
    return json.dumps({"id": "c1", "object": "chat.completion.chunk",
                       "choices": [{"index": 0, "delta": delta, "finish_reason": finish}]})


class FakeChatModel:
    """An OpenAI-compatible server on 127.0.0.1 that streams what each test scripts: ``script(handler,
    body)`` answers one request; ``requests`` keeps each request's headers and JSON body."""

    def __init__(self) -> None:
        self.requests: list[tuple[dict, dict]] = []
        self.script: Callable[[BaseHTTPRequestHandler, dict], None] = lambda handler, body: None
        fake = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_POST(self):  # noqa: N802 (http.server's name)
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                fake.requests.append(({k.lower(): v for k, v in self.headers.items()}, body))
                try:
                    fake.script(self, body)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the adapter gave up on a slow reply

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_port}/v1"
        threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def stream(pieces: list[str], gate: threading.Event | None = None, after: int = 0, done: bool = True, pause=0.0):
    """A script streaming ``pieces`` as SSE chunks (chunked encoding); with ``gate``, it waits for the
    gate after the first ``after`` pieces (and breaks off when it stays shut); ``done``: ends with a
    finish chunk and ``[DONE]``."""

    def script(handler: BaseHTTPRequestHandler, body: dict) -> None:
        handler.send_response(200)
        handler.send_header("Content-Type", "text/event-stream")
        handler.send_header("Transfer-Encoding", "chunked")
        handler.end_headers()

        def send(data: str) -> None:
            raw = data.encode()
            handler.wfile.write(b"%x\r\n%s\r\n" % (len(raw), raw))
            handler.wfile.flush()

        send(f"data: {json.dumps({'choices': [{'index': 0, 'delta': {'role': 'assistant'}}]})}\n\n")
        for i, piece in enumerate(pieces):
            if gate is not None and i == after and not gate.wait(20):
                return  # never opened: the reply breaks off here
            time.sleep(pause)
            send(f"data: {chunk(piece)}\n\n")
        if done:
            send(f"data: {chunk(finish='stop')}\n\ndata: [DONE]\n\n")
            handler.wfile.write(b"0\r\n\r\n")
        handler.close_connection = True

    return script


def answer(status: int, body: dict | str, content_type: str = "application/json"):
    def script(handler: BaseHTTPRequestHandler, request: dict) -> None:
        raw = (body if isinstance(body, str) else json.dumps(body)).encode()
        handler.send_response(status)
        handler.send_header("Content-Type", content_type)
        handler.send_header("Content-Length", str(len(raw)))
        handler.end_headers()
        handler.wfile.write(raw)

    return script


@pytest.fixture(scope="module")
def fake():
    server = FakeChatModel()
    yield server
    server.close()


@pytest.fixture(scope="module")
def client(fake, tmp_path_factory):
    bot = OpenAIChatBot(fake.url, "tiny-llm", key=KEY, system=SYSTEM, timeout=2.0)
    config = ServeConfig(cache=tmp_path_factory.mktemp("chat") / "cache.sqlite3", rate_limit=0, bot=bot,
                         default_model="baseline", stream_model="baseline", chat_history=2)
    with TestClient(create_app(config)) as client:
        yield client


def tokens(text: str) -> list[str]:
    """``text`` in pieces of a word or less, as a chat model streams it."""
    return [word + " " for word in text.split(" ")[:-1]] + [text.split(" ")[-1]]


def test_the_url_is_a_base_url_or_the_full_completions_url():
    assert completions_url("http://127.0.0.1:11434/v1") == "http://127.0.0.1:11434/v1/chat/completions"
    assert completions_url("https://api.openai.com/v1/") == "https://api.openai.com/v1/chat/completions"
    assert completions_url("http://h:8080/v1/chat/completions") == "http://h:8080/v1/chat/completions"
    for bad in ("file:///etc/passwd", "127.0.0.1:8080/v1", "http://h/v1?key=x"):
        with pytest.raises(VispeechError, match="chat URL"):
            completions_url(bad)
    assert KEY not in repr(OpenAIChatBot("http://h/v1", "m", key=KEY))


def test_the_adapter_sends_the_conversation_and_reads_the_streamed_reply(fake):
    fake.script = stream(["Hel", "lo!", " How are", " you?"])
    bot = OpenAIChatBot(fake.url, "tiny-llm", key=KEY, system=SYSTEM)
    history = [ChatTurn("user", "Hi"), ChatTurn("assistant", "Hello."), ChatTurn("user", "Again")]
    assert list(bot.stream(history)) == ["Hel", "lo!", " How are", " you?"]
    headers, body = fake.requests[-1]
    assert headers["authorization"] == f"Bearer {KEY}" and headers["accept"] == "text/event-stream"
    assert body == {"model": "tiny-llm", "stream": True, "messages": [
        {"role": "system", "content": SYSTEM}, {"role": "user", "content": "Hi"},
        {"role": "assistant", "content": "Hello."}, {"role": "user", "content": "Again"}]}
    fake.script = answer(200, {"choices": [{"message": {"content": "Whole."}}]})  # a server that does not stream
    assert list(OpenAIChatBot(fake.url).stream([ChatTurn("user", "x")])) == ["Whole."]
    headers, body = fake.requests[-1]
    assert "authorization" not in headers and "model" not in body and body["messages"][0]["role"] == "user"


def test_each_sentence_gets_its_own_language():
    reply = "Sure! In Swedish you say: Hej, hur mår du? Ja, det är fint väder idag. And that means hello."
    reader, got = ReplyReader(["en", "sv"], "en"), []
    for piece in tokens(reply):
        got += reader.feed(piece)
    got += reader.finish()
    assert [(c.spoken, c.language) for c in got] == [
        ("Sure!", "en"), ("In Swedish you say:", "en"), ("Hej, hur mår du?", "sv"),  # "Hej," alone was unsure
        ("Ja, det är fint väder idag.", "sv"), ("And that means hello.", "en")]
    assert [c.last for c in got] == [False] * 4 + [True]
    unsure = ReplyReader(["en", "sv"], "sv")
    assert [(c.spoken, c.language) for c in unsure.feed("Ok. ") + unsure.finish()] == [("Ok.", "sv")]  # the page's


def _chat(ws, message: str, session: str | None = None, gate: threading.Event | None = None) -> list[dict]:
    """A chat message over the stream: its messages until ``end`` or ``error``; the gate is set once
    the first audio has come."""
    ws.send_json({"type": "chat", "message": message, "language": "en", "session": session})
    messages = []
    while True:
        messages.append(ws.receive_json())
        if gate is not None and messages[-1]["type"] == "audio":
            gate.set()
        if messages[-1]["type"] in ("end", "error"):
            return messages


def test_the_reply_is_spoken_clause_by_clause_as_it_streams_in(client, fake, monkeypatch):
    from vispeech.text_stream import SpeechTimeline

    voices = []  # what espeak-ng was asked to say, in which language
    asked = SpeechTimeline.clause

    def spied(self, text, language, *args, **kwargs):
        voices.append((text, language))
        return asked(self, text, language, *args, **kwargs)

    monkeypatch.setattr(SpeechTimeline, "clause", spied)
    gate = threading.Event()
    first = "Hello there, my friend! "
    rest = "Hej, hur mår du idag? I hope you are well."
    fake.script = stream(tokens(first) + tokens(rest), gate=gate, after=len(tokens(first)) + 1)
    with client.websocket_connect("/api/stream") as ws:
        messages = _chat(ws, "Say hello in two languages.", gate=gate)
        kinds = [m["type"] for m in messages]
        # the model held the rest of its reply back until the first audio came (else it broke off)
        assert kinds[0] == "start" and kinds[1] == "reply" and kinds[-1] == "end"
        replies = [m for m in messages if m["type"] == "reply"]
        session = replies[0]["session"]
        assert [(m["text"], m["language"]) for m in replies] == [
            ("Hello there,", "en"), ("my friend!", "en"), ("Hej, hur mår du idag?", "sv"), ("I hope you are well.", "en")]
        assert all(m["session"] == session for m in replies)
        # each clause in its own language's voice: the Swedish one's audio is espeak-ng's Swedish
        assert voices == [(m["text"], m["language"]) for m in replies]
        sv = replies[2]
        start, end = messages.index(sv), messages.index(replies[3])
        samples = sum(len(base64.b64decode(m["pcm16"])) // 2 for m in messages[start:end] if m["type"] == "audio")
        assert samples == pytest.approx(len(synthesize(sv["text"], "sv").audio), rel=0.01)
        assert messages[-1]["duration"] == pytest.approx(
            sum(len(base64.b64decode(m["pcm16"])) // 2 for m in messages if m["type"] == "audio") / 22050)

        fake.script = stream(tokens("Fine, thanks."))  # the next message goes with the history
        assert _chat(ws, "And you?", session)[-1]["type"] == "end"
    sent = fake.requests[-1][1]["messages"]
    assert sent == [{"role": "system", "content": SYSTEM}, {"role": "user", "content": "Say hello in two languages."},
                    {"role": "assistant", "content": first + rest}, {"role": "user", "content": "And you?"}]


def test_a_posted_chat_speaks_each_sentence_in_its_language(client, fake, monkeypatch):
    """POST /api/chat speaks a reply in two languages as the stream does: clause by clause, the
    Swedish sentence in the Swedish voice, on the stream's channels and timeline (cached like
    any answer); a reply in one language is spoken whole, with its phones."""
    import io
    import math

    import numpy as np
    from scipy.io import wavfile

    import vispeech.frontends.espeak as espeak

    voices = []

    def spied(text, language, *args, **kwargs):
        voices.append((text, language))
        return synthesize(text, language, *args, **kwargs)

    monkeypatch.setattr(espeak, "synthesize", spied)
    reply = "Hello there, my friend! Hej, hur mår du idag? I hope you are well."
    fake.script = stream(tokens(reply))
    answer = client.post("/api/chat", json={"message": "Say hello in two languages.", "life": ["blink"]})
    assert answer.status_code == 200, answer.text
    body = answer.json()
    assert (body["reply"], body["language"]) == (reply, "en")
    assert voices == [("Hello there,", "en"), ("my friend!", "en"), ("Hej, hur mår du idag?", "sv"),
                      ("I hope you are well.", "en")]
    speech = body["speech"]
    animation = speech["animation"]
    rate, samples = wavfile.read(io.BytesIO(client.get(speech["audio_url"]).content))
    assert animation["n_frames"] == len(animation["frames"]) == math.ceil(len(samples) / rate * 30.0 - 1e-6)
    assert animation["phones"] is None and speech["text"] == reply and not speech["cached"]
    sv = synthesize("Hej, hur mår du idag?", "sv").audio
    assert len(samples) > len(sv) + 3 * 22050 // 2  # the English clauses too
    with client.websocket_connect("/api/stream") as ws:
        fake.script = stream(tokens(reply))
        streamed = _chat(ws, "Again, please.")
    assert streamed[0]["channels"] + ["eyeBlinkLeft", "eyeBlinkRight"] == animation["channels"]
    frames = np.array([row for m in streamed if m["type"] == "frames" for row in m["frames"]])
    jaw = animation["channels"].index("jawOpen")
    assert len(frames) == pytest.approx(animation["n_frames"], abs=3)  # espeak-ng's timing varies a little
    n = min(len(frames), animation["n_frames"])
    assert np.abs(frames[:n, jaw] - np.array(animation["frames"])[:n, jaw]).mean() < 0.02
    fake.script = stream(tokens(reply))
    again = client.post("/api/chat", json={"message": "Once more.", "life": ["blink"]}).json()["speech"]
    assert again["cached"] and again["audio_url"] == speech["audio_url"]
    voices.clear()
    fake.script = stream(tokens("One language, one voice."))
    whole = client.post("/api/chat", json={"message": "Just English."}).json()["speech"]
    assert voices == [("One language, one voice.", "en")] and whole["animation"]["phones"] is not None


def test_history_is_bounded_and_kept_apart(client, fake):
    fake.script = stream(["Reply one."])
    first = client.post("/api/chat", json={"message": "One", "speak": False}).json()
    session = first["session"]
    assert first["reply"] == "Reply one." and first["language"] == "en" and first["speech"] is None
    for n in ("two", "three"):
        fake.script = stream([f"Reply {n}."])
        assert client.post("/api/chat", json={"message": n, "session": session, "speak": False}).json()["session"] == session
    fake.script = stream(["Other."])
    other = client.post("/api/chat", json={"message": "Who?", "speak": False}).json()
    assert other["session"] != session
    assert [m["content"] for m in fake.requests[-1][1]["messages"]] == [SYSTEM, "Who?"]  # none of the other's
    fake.script = stream(["Four."])
    client.post("/api/chat", json={"message": "four", "session": session, "speak": False})
    assert [m["content"] for m in fake.requests[-1][1]["messages"]] == [  # chat_history=2: the last two exchanges
        SYSTEM, "two", "Reply two.", "three", "Reply three.", "four"]
    unknown = client.post("/api/chat", json={"message": "hi", "session": "not-one-of-ours", "speak": False})
    assert unknown.status_code == 404 and "unknown or expired chat session" in unknown.json()["detail"]
    bad = client.post("/api/chat", json={"message": "hi", "session": "../x", "speak": False})
    assert bad.status_code == 422


def test_sessions_are_bounded_in_number_turns_characters_and_time():
    now = [0.0]
    sessions = ChatSessions(max_sessions=2, max_turns=3, max_chars=30, idle_seconds=10, clock=lambda: now[0])
    a, b = sessions.open(None), sessions.open(None)
    assert len({a, b}) == 2 and len(a) >= 22  # 128 random bits
    for i in range(5):
        sessions.add(a, f"m{i}", f"r{i}")
    assert [t.content for t in sessions.history(a)] == ["m2", "r2", "m3", "r3", "m4", "r4"]
    sessions.add(a, "x" * 12, "y" * 12)  # over 30 characters: the oldest go
    assert [t.content for t in sessions.history(a)] == ["m4", "r4", "x" * 12, "y" * 12]
    sessions.open(a)
    c = sessions.open(None)  # a third: the one used longest ago (b) goes
    assert len(sessions) == 2 and sessions.history(b) == []
    with pytest.raises(UnknownSession):
        sessions.open(b)
    now[0] = 11.0
    with pytest.raises(UnknownSession):
        sessions.open(c)  # idle too long
    assert len(sessions) == 0


@pytest.mark.parametrize(("script", "status", "words"), [
    (None, 502, "the chat service is unreachable"),
    (answer(401, {"error": {"message": f"Incorrect API key provided: {KEY}"}}), 502, "refused the key (HTTP 401)"),
    (answer(500, {"error": {"message": "model crashed"}}), 502, "HTTP 500: model crashed"),
    (answer(404, {"error": "model 'tiny-llm' not found"}), 502, "HTTP 404: model 'tiny-llm' not found"),
    (answer(404, "<h1>Not Found</h1>", "text/html"), 502, "HTTP 404 (is the chat URL the API's base"),
    (answer(200, "<html>Open WebUI</html>", "text/html"), 502, "a web page, not chat completions"),
    (answer(200, "data: {not json\n\n", "text/event-stream"), 502, "an event that is not JSON"),
    (answer(200, f"data: {chunk('Hello')}\n\n", "text/event-stream"), 502, "broke off before its end"),
    (stream(["Hello", " there."], done=False), 502, "broke off"),
    (stream(["Slow."], pause=3.0), 504, "sent nothing for 2 s"),
])
def test_upstream_failures_are_one_clear_error(client, fake, caplog, script, status, words):
    if script is None:
        client.app.state.service.config.bot.url = "http://127.0.0.1:9/v1/chat/completions"  # nothing listens
    else:
        fake.script = script
    try:
        with caplog.at_level(logging.INFO):
            failed = client.post("/api/chat", json={"message": "Hello", "speak": False})
            assert failed.status_code == status and words in failed.json()["detail"]
            with client.websocket_connect("/api/stream") as ws:
                messages = _chat(ws, "Hello")
                assert messages[-1]["type"] == "error" and words in messages[-1]["message"]
                fake.script = stream(["All good."])  # the connection and the next chat go on
                client.app.state.service.config.bot.url = completions_url(fake.url)
                assert [m["text"] for m in _chat(ws, "Again") if m["type"] == "reply"] == ["All good."]
    finally:
        client.app.state.service.config.bot.url = completions_url(fake.url)
    assert KEY not in caplog.text and KEY not in failed.text
    assert "Traceback" not in caplog.text


def test_the_command_takes_the_key_from_the_environment_and_never_shows_it(fake, monkeypatch, tmp_path):
    from click.testing import CliRunner

    import vispeech.serve
    from vispeech.cli import main

    made = []

    def create_app(config):  # the settings the command made, and no server
        made.append(config)
        raise VispeechError("not starting in a test")

    monkeypatch.setattr(vispeech.serve, "create_app", create_app)
    monkeypatch.setenv("VISPEECH_CHAT_KEY", KEY)
    prompt = tmp_path / "system.txt"
    prompt.write_text(SYSTEM + "\n", encoding="utf-8")
    result = CliRunner().invoke(main, ["serve", "--chat-url", fake.url, "--chat-model", "tiny-llm",
                                       "--chat-system-file", str(prompt), "--reply-languages", "en, de"])
    assert result.exit_code == 2 and "not starting in a test" in result.output
    bot = made[0].bot
    assert (bot.url, bot.model, bot.key, bot.system) == (completions_url(fake.url), "tiny-llm", KEY, SYSTEM)
    assert made[0].reply_languages == ("en", "de")
    back = ServeConfig.from_json(made[0].to_json())  # to the server's other processes
    assert vars(back.bot) == vars(bot) and back.reply_languages == ("en", "de")
    help_text = CliRunner().invoke(main, ["serve", "--help"]).output
    assert "--chat-url" in help_text and "VISPEECH_CHAT_KEY" in help_text and KEY not in help_text + result.output
    both = CliRunner().invoke(main, ["serve", "--chat-url", fake.url, "--chat-system", "x", "--chat-system-file",
                                     str(prompt)])
    assert both.exit_code == 2 and "not both" in both.output


def test_a_slow_or_abandoned_chat_holds_up_no_other(client, fake):
    """While one chat waits on a slow model, another is answered; a client that leaves mid-reply
    frees its place (the server waits on no chat afterwards)."""
    gate = threading.Event()
    slow, quick = stream(tokens("Let me think. About that."), gate=gate, after=4), stream(["Quick."])
    fake.script = lambda handler, body: (slow if body["messages"][-1]["content"] == "slow" else quick)(handler, body)
    service = client.app.state.service
    with client.websocket_connect("/api/stream") as waiting, client.websocket_connect("/api/stream") as other:
        waiting.send_json({"type": "chat", "message": "slow"})
        assert waiting.receive_json()["type"] == "start"  # its first clause is spoken; the rest waits on the model
        assert [m["text"] for m in _chat(other, "quick") if m["type"] == "reply"] == ["Quick."]
        gate.set()
        while waiting.receive_json()["type"] != "end":
            pass
    gate.clear()
    with client.websocket_connect("/api/stream") as leaving:
        leaving.send_json({"type": "chat", "message": "slow"})
        assert leaving.receive_json()["type"] == "start"
    gate.set()  # the model goes on writing to a chat nobody reads
    deadline = time.monotonic() + 10
    while service.chatting and time.monotonic() < deadline:
        time.sleep(0.05)
    assert service.chatting == 0
