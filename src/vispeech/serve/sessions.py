"""Chat sessions: each conversation's history, by a session id the server draws, bounded in
memory (sessions, turns and characters kept, time idle)."""

from __future__ import annotations

import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

from vispeech.serve.bot import ChatTurn


class UnknownSession(LookupError):
    """A chat session id the server does not hold (never drawn, expired or dropped); the server answers 404."""


@dataclass
class _Session:
    turns: list[ChatTurn] = field(default_factory=list)
    used: float = 0.0


class ChatSessions:
    """Conversations by session id: at most ``max_sessions`` (the one used longest ago goes first),
    each keeping its last ``max_turns`` exchanges (a user message and the reply) within
    ``max_chars`` characters, dropped after ``idle_seconds`` unused.

    An id is 128 random bits (URL-safe base64) drawn by :meth:`open`: a client cannot name another's
    session, so no session reads another's history. Thread-safe.
    """

    def __init__(
        self,
        max_sessions: int = 1000,
        max_turns: int = 10,
        max_chars: int = 8000,
        idle_seconds: float = 1800.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_sessions, self.max_turns, self.max_chars = max_sessions, max_turns, max_chars
        self.idle_seconds, self.clock = idle_seconds, clock
        self._sessions: OrderedDict[str, _Session] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._sessions)

    def open(self, session: str | None) -> str:
        """The id of ``session`` (``None``: a new one, drawn now); :class:`UnknownSession` for one not held."""
        now = self.clock()
        with self._lock:
            self._expire(now)
            if session is None:
                session = secrets.token_urlsafe(16)
                self._sessions[session] = _Session(used=now)
                while len(self._sessions) > self.max_sessions:
                    self._sessions.popitem(last=False)
            elif session not in self._sessions:
                raise UnknownSession(
                    "unknown or expired chat session: send the message without a session to start a new one"
                )
            self._sessions[session].used = now
            self._sessions.move_to_end(session)
            return session

    def history(self, session: str) -> list[ChatTurn]:
        """The turns ``session`` keeps, oldest first (none once it has gone)."""
        with self._lock:
            kept = self._sessions.get(session)
            return [] if kept is None else list(kept.turns)

    def add(self, session: str, message: str, reply: str) -> None:
        """Keep the exchange ``message`` → ``reply`` in ``session`` (not when it has gone), dropping the
        oldest exchanges beyond the bounds."""
        with self._lock:
            kept = self._sessions.get(session)
            if kept is None:
                return
            kept.turns += [ChatTurn("user", message), ChatTurn("assistant", reply)]
            del kept.turns[: max(0, len(kept.turns) - 2 * self.max_turns)]
            while kept.turns and sum(len(turn.content) for turn in kept.turns) > self.max_chars:
                del kept.turns[:2]
            kept.used = self.clock()
            self._sessions.move_to_end(session)

    def _expire(self, now: float) -> None:
        while self._sessions:
            oldest = next(iter(self._sessions.values()))
            if now - oldest.used <= self.idle_seconds:
                return
            self._sessions.popitem(last=False)
