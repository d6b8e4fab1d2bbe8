"""Chat bots behind ``POST /api/chat`` and the stream's chat messages: the :class:`ChatBot`
protocol (a message in, a reply out) and its rule bot, and the :class:`ChatModel` protocol (a
conversation in, the reply in pieces as they come; :class:`~vispeech.serve.llm.OpenAIChatBot`).

The server asks its bot for a reply and speaks it; any object with a
``reply(message, language) -> str`` method will do (a database of answers), and any with
``stream(conversation) -> Iterator[str]`` is told the session's conversation so far.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Sequence
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
