"""Chat bots behind ``POST /api/chat`` and the stream's chat messages: the :class:`ChatBot`
protocol (a message in, a reply out) and its rule bot, and the :class:`ChatModel` protocol (a
conversation in, the reply in pieces as they come; :class:`~vispeech.serve.llm.OpenAIChatBot`).

The server asks its bot for a reply and speaks it; any object with a
``reply(message, language) -> str`` method will do (a database of answers), and any with
``stream(conversation) -> Iterator[str]`` is told the session's conversation so far.
"""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Literal, Protocol, runtime_checkable

from vispeech.errors import VispeechError
from vispeech.pipeline import GREETINGS


class ChatBotError(RuntimeError):
    """The bot could not answer (its service failed); the server answers 502."""


class ChatBotTimeout(ChatBotError):
    """The bot's service took too long; the server answers 504."""


@dataclass(frozen=True)
class ChatTurn:
    """One message of a conversation: the user's or the assistant's (the bot's reply)."""

    role: Literal["user", "assistant"]
    content: str


@runtime_checkable
class ChatBot(Protocol):
    """Anything that answers a chat message in a language (a code of ``vispeech languages``) with
    text; ``languages`` are the codes it answers in, ``None`` for any."""

    @property
    def languages(self) -> tuple[str, ...] | None: ...  # read-only: a class attribute will do

    def reply(self, message: str, language: str) -> str: ...


@runtime_checkable
class ChatModel(Protocol):
    """A chat model that continues a conversation (its last turn the user's): the reply's text in
    pieces as they are written. It answers in any language."""

    def stream(self, conversation: Sequence[ChatTurn]) -> Iterator[str]: ...


_RULES: dict[str, list[tuple[str, str]]] = {
    # (rule name, pattern) in priority order; the first match answers
    "sv": [
        ("time", r"vad är klockan|hur mycket är klockan|\bklockan\b|\btiden\b"),
        ("name", r"vad heter du|vem är du|ditt namn"),
        ("help", r"\bhjälp|vad kan du|hur fungerar"),
        ("thanks", r"\btack"),
        ("greeting", r"\b(hej|hejsan|hallå|tjena|tja|goddag|god (morgon|dag|middag|kväll))\b"),
    ],
    "en": [
        ("time", r"what time|the time|time is it|\bclock\b"),
        ("name", r"your name|who are you|what are you called"),
        ("help", r"\bhelp\b|what can you do|how does (this|it) work"),
        ("thanks", r"\bthanks?\b|thank you|\bcheers\b"),
        ("greeting", r"\b(hello|hi|hey|greetings|good (morning|afternoon|evening|day))\b"),
    ],
}

_REPLIES: dict[str, dict[str, str]] = {
    "sv": {
        "greeting": GREETINGS["sv"],
        "help": "Jag är en talande avatar. Skriv till mig så svarar jag med rösten. "
        "Fråga gärna vad jag heter eller vad klockan är.",
        "name": "Jag heter {name}.",
        "time": "Klockan är {time}.",
        "thanks": "Varsågod!",
        "fallback": "Det förstod jag tyvärr inte. Skriv hjälp så berättar jag vad jag kan.",
    },
    "en": {
        "greeting": GREETINGS["en"],
        "help": "I am a talking avatar. Write to me and I will answer out loud. You can ask me my name or the time.",
        "name": "My name is {name}.",
        "time": "It is {time}.",
        "thanks": "You're welcome!",
        "fallback": "Sorry, I did not understand that. Type help to hear what I can do.",
    },
}


class RuleBot:
    """A small FAQ bot in Swedish and English: greetings, help, its name, the time, thanks.

    Anything else gets a fallback answer pointing to help. ``clock`` gives the current time
    (local time by default).
    """

    languages = ("sv", "en")

    def __init__(self, name: str = "Vera", clock: Callable[[], datetime] = datetime.now) -> None:
        self.name = name
        self.clock = clock
        self._rules = {
            language: [(rule, re.compile(pattern, re.IGNORECASE)) for rule, pattern in rules]
            for language, rules in _RULES.items()
        }

    def reply(self, message: str, language: str) -> str:
        """The answer to ``message`` in ``language``."""
        if language not in self._rules:
            raise VispeechError(
                f"the built-in chat bot speaks sv and en, not {language!r}; connect a chat service "
                "(vispeech serve --chat-url) for other languages"
            )
        rule = next((rule for rule, pattern in self._rules[language] if pattern.search(message)), "fallback")
        return _REPLIES[language][rule].format(name=self.name, time=f"{self.clock():%H:%M}")


class HTTPChatBot:
    """Relays messages to an external chat service over HTTP(S).

    Each message is POSTed as JSON ``{message_field: message, language_field: language}`` (no
    language when ``language_field`` is ``None``) with ``headers``; the reply is read from the
    JSON answer at ``reply_field``, a dotted path that may index lists
    (``"choices.0.message.content"``). Failures raise :class:`ChatBotError`.
    """

    max_reply_bytes = 1 << 20
    languages = None  # any: the language is passed through

    def __init__(
        self,
        url: str,
        *,
        message_field: str = "message",
        language_field: str | None = "language",
        reply_field: str = "reply",
        headers: Mapping[str, str] | None = None,
        timeout: float = 10.0,
    ) -> None:
        if not re.match(r"^https?://", url, re.IGNORECASE):
            raise VispeechError(f"chat bot URL must start with http:// or https://, got {url!r}")
        self.url = url
        self.message_field = message_field
        self.language_field = language_field
        self.reply_field = reply_field
        self.headers = dict(headers or {})
        self.timeout = timeout

    def __repr__(self) -> str:
        return f"HTTPChatBot({self.url!r})"

    def reply(self, message: str, language: str) -> str:
        """POST ``message`` to the service and return the text at ``reply_field`` of its answer."""
        payload = {self.message_field: message}
        if self.language_field is not None:
            payload[self.language_field] = language
        request = urllib.request.Request(
            self.url,
            data=json.dumps(payload).encode(),
            method="POST",
            headers={"Content-Type": "application/json", "Accept": "application/json", **self.headers},
        )
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as response:  # noqa: S310 (scheme checked)
                body = response.read(self.max_reply_bytes + 1)
        except urllib.error.HTTPError as exc:
            raise ChatBotError(f"chat service answered HTTP {exc.code}") from None
        except (urllib.error.URLError, OSError) as exc:
            raise ChatBotError(f"chat service unreachable: {getattr(exc, 'reason', exc)}") from None
        if len(body) > self.max_reply_bytes:
            raise ChatBotError("chat service answer is too large")
        try:
            value = json.loads(body)
            for part in self.reply_field.split("."):
                value = value[int(part)] if isinstance(value, list) else value[part]
        except (ValueError, KeyError, IndexError, TypeError):
            raise ChatBotError(f"chat service answer has no text at {self.reply_field!r}") from None
        if not isinstance(value, str) or not value.strip():
            raise ChatBotError(f"chat service answer at {self.reply_field!r} is not a non-empty text")
        return value.strip()
