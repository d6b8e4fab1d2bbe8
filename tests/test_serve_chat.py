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

from vispeech.errors import VispeechError  # noqa: E402
from vispeech.frontends.espeak import synthesize  # noqa: E402
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
    gate after the first ``after`` pieces; ``done``: ends with a finish chunk and ``[DONE]``."""

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
            if gate is not None and i == after:
                gate.wait(30)
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

