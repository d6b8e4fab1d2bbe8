"""A chat model behind an OpenAI-compatible chat-completions endpoint (OpenAI, llama.cpp's server,
Ollama, vLLM, LM Studio, ...): :class:`OpenAIChatBot` sends the conversation and reads the reply
as it streams in (Server-Sent Events), so the avatar can speak its first clause while the rest is
being written.

Failures of the service (unreachable, refused, an error status, a broken or malformed stream) raise
:class:`~vispeech.serve.bot.ChatBotError` with one line saying what went wrong (the server answers
502), a service too slow :class:`~vispeech.serve.bot.ChatBotTimeout` (504). The key is sent in the
``Authorization`` header and nowhere else: not in errors, logs or ``repr``.
"""

from __future__ import annotations

import http.client
import json
import re
import time
import urllib.error
import urllib.request
from collections.abc import Iterable, Iterator, Sequence
from typing import IO, Any

from vispeech.errors import VispeechError
from vispeech.serve.bot import ChatBotError, ChatBotTimeout, ChatTurn

COMPLETIONS_PATH = "/chat/completions"
"""What :func:`completions_url` adds to a base URL."""
_URL_HINT = " (is the chat URL the API's base, as http://HOST:PORT/v1?)"


def completions_url(url: str) -> str:
    """The chat-completions URL of ``url``: a base URL as OpenAI's SDKs take it
    (``http://127.0.0.1:11434/v1`` → ``.../v1/chat/completions``), or one that already ends in
    ``/chat/completions``. Raises :class:`VispeechError` for anything but ``http(s)://host...``."""
    url = url.strip()
    if not re.match(r"^https?://[^/\s?#]+(/[^\s?#]*)?$", url, re.IGNORECASE):
        raise VispeechError(f"the chat URL must be http(s)://HOST[:PORT][/PATH] with no query, got {url!r}")
    url = url.rstrip("/")
    return url if url.endswith(COMPLETIONS_PATH) else url + COMPLETIONS_PATH


class OpenAIChatBot:
    """A chat model at an OpenAI-compatible ``url`` (see :func:`completions_url`), asked for ``model``
    (``None``: the field is left out, for servers that serve one model) with bearer ``key`` (``None``:
    no ``Authorization`` header) and the ``system`` prompt before the conversation.

    ``timeout`` bounds each wait for the service (connecting, and each piece of the reply), and
    ``max_seconds`` the whole reply; a reply over ``max_reply_bytes`` is refused.
    """

    languages = None  # it answers in any language; each sentence is spoken in its own
    max_reply_bytes = 1 << 20

    def __init__(
        self,
        url: str,
        model: str | None = None,
        *,
        key: str | None = None,
        system: str | None = None,
        timeout: float = 60.0,
        max_seconds: float = 120.0,
    ) -> None:
        self.url = completions_url(url)
        self.model = model or None
        self.key = key or None
        self.system = system or None
        self.timeout = timeout
        self.max_seconds = max_seconds

    def __repr__(self) -> str:  # never the key
        return f"OpenAIChatBot({self.url!r}, model={self.model!r})"

    def settings(self) -> dict[str, Any]:
        """The arguments that make this bot again (for the server's other processes)."""
        keys = ("url", "model", "key", "system", "timeout", "max_seconds")
        return {name: getattr(self, name) for name in keys}

    def request_body(self, conversation: Sequence[ChatTurn]) -> dict[str, Any]:
        """The JSON body asking for the next reply of ``conversation`` (the system prompt put first)."""
        messages = [{"role": "system", "content": self.system}] if self.system else []
        messages += [{"role": turn.role, "content": turn.content} for turn in conversation]
        body: dict[str, Any] = {"messages": messages, "stream": True}
        if self.model is not None:
            body["model"] = self.model
        return body

    def stream(self, conversation: Sequence[ChatTurn]) -> Iterator[str]:
        """The reply to ``conversation`` (the last turn the user's), in pieces as they arrive."""
        headers = {"Content-Type": "application/json", "Accept": "text/event-stream"}
        if self.key is not None:
            headers["Authorization"] = f"Bearer {self.key}"
        data = json.dumps(self.request_body(conversation)).encode()
        request = urllib.request.Request(self.url, data=data, method="POST", headers=headers)
        try:
            response = urllib.request.urlopen(request, timeout=self.timeout)  # noqa: S310 (scheme checked)
        except urllib.error.HTTPError as exc:
            raise _status_error(exc.code, exc.read(4096)) from None
        except TimeoutError:
            raise ChatBotTimeout(f"the chat service did not answer within {self.timeout:g} s") from None
        except (urllib.error.URLError, OSError) as exc:
            raise ChatBotError(f"the chat service is unreachable ({getattr(exc, 'reason', exc)})") from None
        with response:
            kind = response.headers.get_content_type()
            if kind == "application/json":  # it did not stream
                yield _whole_reply(response.read(self.max_reply_bytes + 1), self.max_reply_bytes)
                return
            if kind == "text/html":
                raise ChatBotError(f"the chat service answered a web page, not chat completions{_URL_HINT}")
            yield from _deltas(_events(self._lines(response)))

    def _lines(self, response: IO[bytes]) -> Iterator[bytes]:
        """The response's lines, within the time and size limits."""
        deadline, size = time.monotonic() + self.max_seconds, 0
        while True:
            try:
                line = response.readline(self.max_reply_bytes)
            except TimeoutError:
                raise ChatBotTimeout(f"the chat service sent nothing for {self.timeout:g} s") from None
            except (OSError, http.client.HTTPException) as exc:
                raise ChatBotError(f"the chat service's reply broke off ({type(exc).__name__})") from None
            if not line:
                return
            size += len(line)
            if size > self.max_reply_bytes:
                raise ChatBotError(f"the chat service's reply is over {self.max_reply_bytes} bytes")
            if time.monotonic() > deadline:
                raise ChatBotTimeout(f"the chat service's reply took over {self.max_seconds:g} s")
            yield line


def _events(lines: Iterable[bytes]) -> Iterator[str]:
    """The data of each Server-Sent Event of ``lines`` (comments and other fields skipped)."""
    data: list[str] = []
    for raw in lines:
        line = raw.decode("utf-8", "replace").rstrip("\r\n")
        if not line:
            if data:
                yield "\n".join(data)
            data = []
        elif line.startswith("data:"):
            data.append(line[5:].removeprefix(" "))
    if data:
        yield "\n".join(data)


def _deltas(events: Iterable[str]) -> Iterator[str]:
    """The text of each chat-completion chunk; ends at ``[DONE]`` (or after a chunk that says why
    it finished, for services that send no ``[DONE]``)."""
    finished = False
    for event in events:
        if event.strip() == "[DONE]":
            return
        try:
            chunk = json.loads(event)
        except ValueError:
            raise ChatBotError(f"the chat service sent an event that is not JSON: {event[:80]!r}") from None
        if not isinstance(chunk, dict):
            raise ChatBotError("the chat service sent an event that is not a JSON object")
        if "error" in chunk:
            raise ChatBotError(f"the chat service failed: {_message(chunk)}")
        for choice in chunk.get("choices") or []:  # a usage chunk has none
            try:
                content = (choice.get("delta") or {}).get("content")
            except AttributeError:
                raise ChatBotError("the chat service sent a chunk without choices[].delta") from None
            if isinstance(content, str) and content:
                yield content
            finished = finished or bool(choice.get("finish_reason"))
    if not finished:
        raise ChatBotError("the chat service's reply broke off before its end")


def _whole_reply(body: bytes, limit: int) -> str:
    """The text of a chat completion that came whole (a service that does not stream)."""
    if len(body) > limit:
        raise ChatBotError(f"the chat service's reply is over {limit} bytes")
    try:
        content = json.loads(body)["choices"][0]["message"]["content"]
    except (ValueError, KeyError, IndexError, TypeError):
        raise ChatBotError("the chat service's answer has no choices[0].message.content") from None
    if not isinstance(content, str):
        raise ChatBotError("the chat service's answer has no text")
    return content


def _status_error(status: int, body: bytes) -> ChatBotError:
    """The error of a refusal with HTTP ``status`` (the service's own message where it gives one,
    but for a refused key: its message may quote the key)."""
    if status in (401, 403):
        return ChatBotError(f"the chat service refused the key (HTTP {status}): check --chat-key or $VISPEECH_CHAT_KEY")
    try:
        said = _message(json.loads(body))
    except ValueError:
        said = ""
    kind = ChatBotTimeout if status in (408, 504) else ChatBotError
    hint = _URL_HINT if status in (404, 405) and not said else ""
    return kind(f"the chat service answered HTTP {status}{f': {said}' if said else ''}{hint}")


def _message(answer: Any) -> str:
    """The message of an error answer (``{"error": {"message": ...}}``, ``{"error": "..."}``,
    ``{"detail": ...}``), one line of at most 200 characters."""
    if not isinstance(answer, dict):
        return ""
    error = answer.get("error", answer.get("detail", ""))
    if isinstance(error, dict):
        error = error.get("message", "")
    return " ".join(str(error).split())[:200]
