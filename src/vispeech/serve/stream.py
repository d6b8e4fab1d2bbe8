"""``/api/stream``: texts spoken clause by clause (audio and frames as they are computed), chat
replies spoken clause by clause as the bot writes them, and phone streams (timed phones in,
frames out)."""

from __future__ import annotations

import contextlib
import time
from typing import NamedTuple

from fastapi import APIRouter, WebSocket
from pydantic import ValidationError

from vispeech.alignment.phones import Phone
from vispeech.errors import VispeechError
from vispeech.motion.rigging.calibration import Calibration
from vispeech.pipeline import spoken_text
from vispeech.serve.bot import ChatBotError
from vispeech.serve.connection import Connection, message_json, send_error, send_message, serve_connection
from vispeech.serve.dependencies import Service
from vispeech.serve.errors import REFUSALS, describe_errors
from vispeech.serve.schemas import (
    ChatStreamMessage,
    ClientMessage,
    EndMessage,
    PhonesMessage,
    ReplyMessage,
    StartMessage,
    TextMessage,
    WarningMessage,
)
from vispeech.serve.service import PHONE_WORK_PER_SECOND, TEXT_WORK_PER_CHAR, SpeechService
from vispeech.streaming import PhoneStream, open_phone_stream
from vispeech.text_stream import SpeechTimeline, split_clauses

router = APIRouter()


@router.websocket("/api/stream")
async def stream(websocket: WebSocket, service: Service) -> None:
    """Speech animation as it is computed (see :mod:`vispeech.text_stream` and :mod:`vispeech.streaming`)."""
    await serve_connection(websocket, service, StreamConnection)


class StreamConnection(Connection):
    """An ``/api/stream`` connection: texts spoken clause by clause, phone streams."""

    kind = "text"

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        super().__init__(websocket, service, ip)
        self.phones: PhoneStream | None = None
        self.settings: PhoneSettings | None = None
        """What the open phone stream's first message set."""
        self.scale: Calibration | None = None
        """The open phone stream's output scale."""

    def _release(self) -> None:
        if self.phones is not None:
            self.phones.close()

    async def _handle(self, event: dict) -> bool:
        if await self._oversize(event):
            return False
        raw = event.get("text")
        if raw is None:
            await send_error(self.ws, "send JSON text messages")
            return True
        try:
            message = ClientMessage.validate_json(raw)
        except ValidationError as exc:
            await send_error(self.ws, describe_errors(exc.errors(), skip=1, what="message", kinds=_KINDS))
            return True
        try:
            if isinstance(message, TextMessage | ChatStreamMessage):
                if self.phones is not None:
                    raise VispeechError('a phone stream is open: end it with "final": true first')
            if isinstance(message, TextMessage):
                self.service.pay(self.ip, self.service.text_cost(message.text))
                await self._text(message)
            elif isinstance(message, ChatStreamMessage):
                self.service.pay(self.ip, self.service.text_cost(message.message))
                await self._chat(message)
            else:
                await self._phones(message)
            self._worked()
        except REFUSALS as exc:
            if self.phones is not None and self.phones.closed:
                self.phones = None
            await send_error(self.ws, str(exc))
        return True

    def _timeline_settings(self, message: TextMessage | ChatStreamMessage) -> dict:
        """The :class:`SpeechTimeline` settings ``message`` asks for (the server's where it says null)."""
        return {
            "fps": message.fps or self.config.fps,
            "rate": message.rate,
            "scale": self.service.scale(message.scale)[1],
            "voice": message.voice or self.config.voice,
            "life": message.life,
            "seed": message.seed,
        }

    async def _text(self, message: TextMessage) -> None:
        name, model = self.service.model(message.model, stream=True)
        timeline = SpeechTimeline(model, **self._timeline_settings(message))
        clauses = split_clauses(spoken_text(message.text))
        playing: float | None = None  # when the first audio chunk left: the client's playback starts no earlier
        for k, clause in enumerate(clauses):
            begin = timeline.duration  # where the clause's audio starts
            texts = await self._say(timeline, name, clause, message.language, k == len(clauses) - 1)
            now = time.monotonic()
            if playing is None:
                playing = now - begin
            elif now - playing > begin:
                late = now - playing - begin
                await send_message(
                    self.ws,
                    WarningMessage(
                        code="late",
                        seconds=round(late, 3),
                        message=f"the clause at {begin:.2f} s leaves {late:.2f} s after it is due: the server is "
                        "overloaded (buffer more before playing, or try again later)",
                    ),
                )
            for text in texts:
                await self.ws.send_text(text)
        await send_message(self.ws, timeline.end()[0])

    async def _say(self, timeline: SpeechTimeline, model: str, clause: str, language: str, last: bool) -> list[str]:
        """The stream messages (JSON) of saying ``clause`` in ``language`` on ``timeline`` (of the
        model named ``model``), voiced with the other streams' clauses
        (:class:`~vispeech.serve.clauses.ClauseBatcher`)."""
        asked = timeline.clause(clause, language, last)
        voiced = await self.service.clauses.voice(model, asked, len(clause) * TEXT_WORK_PER_CHAR)
        return [message_json(item) for item in timeline.place(voiced)]

    async def _chat(self, message: ChatStreamMessage) -> None:
        """The bot's reply to ``message``, spoken clause by clause as it is written: each clause's
        ``reply`` message, then its frames and audio (after the stream's ``start``); then ``end``."""
        name, model = self.service.model(message.model, stream=True)
        session = self.service.chats.open(message.session)
        timeline = SpeechTimeline(model, **self._timeline_settings(message))
        async with contextlib.aclosing(self.service.chat(message.message, message.language, session)) as clauses:
            async for clause in clauses:
                self.service.bucket.charge(self.ip, self.service.text_cost(clause.spoken))
                first = timeline.sample_rate is None
                start = timeline.duration
                reply = ReplyMessage(session=session, text=clause.text, language=clause.language, start=start)
                texts = await self._say(timeline, name, clause.spoken, clause.language, clause.last)
                texts.insert(1 if first else 0, reply.model_dump_json())  # after the stream's start
                for text in texts:
                    await self.ws.send_text(text)
        if timeline.sample_rate is None:
            raise ChatBotError("the chat bot's reply has nothing to say")
        await send_message(self.ws, timeline.end()[0])

    def _settings(self, message: PhonesMessage) -> PhoneSettings:
        """What ``message`` sets of a phone stream, as the stream takes it."""
        return PhoneSettings(
            message.language or "en",
            self.service.model(message.model, stream=True)[0],
            message.fps or self.config.fps,
            self.service.scale(message.scale)[0],
        )

    def _check_settings(self, message: PhonesMessage, settings: PhoneSettings) -> None:
        """Refuse a later message of a phone stream that would change what its first one set."""
        named = sorted(message.model_fields_set & set(PhoneSettings._fields))
        asked = self._settings(message) if named else settings
        for name in named:
            if getattr(asked, name) != getattr(settings, name):
                raise VispeechError(
                    f"this phone stream's {name} was set by its first message: {getattr(message, name)!r} "
                    'cannot change it (end the stream with "final": true first)'
                )

    async def _open_phones(self, message: PhonesMessage) -> PhoneStream:
        """A phone stream as ``message`` (its first) sets it, its ``start`` message sent."""
        name, model = self.service.model(message.model, stream=True)
        settings = self._settings(message)
        stream = await self._run(open_phone_stream, model, settings.language, settings.fps, kind="phones")
        self.phones, self.settings, self.scale = stream, settings, self.service.scale(message.scale)[1]
        start = StartMessage(
            fps=stream.fps, channels=list(stream.channels), sample_rate=None, model=name, lookahead=stream.lookahead
        )
        await send_message(self.ws, start)
        return stream

    async def _phones(self, message: PhonesMessage) -> None:
        """Frames for ``message``'s phones, pushed in pieces; with ``final`` the rest and ``end``."""
        config, stream = self.config, self.phones
        if stream is not None and self.settings is not None:
            self._check_settings(message, self.settings)
        begin = stream.end if stream is not None else 0.0
        last = max((p.end for p in message.phones), default=begin)
        added = max(0.0, last - begin)
        if added > config.max_message_seconds + 1e-9:
            raise VispeechError(
                f"a phones message may add at most {config.max_message_seconds:g} s of phones "
                f"(this one adds {added:.1f} s): send them in smaller messages"
            )
        if last > config.max_stream_seconds + 1e-9:
            raise VispeechError(
                f"a phone stream may last at most {config.max_stream_seconds:g} s (this message ends at {last:.1f} s)"
            )
        self.service.pay(self.ip, max(config.min_message_cost, added / config.phone_seconds_per_token))
        if stream is None:
            stream = await self._open_phones(message)
        phones = [Phone(p.symbol, p.start, p.end, None, p.stress) for p in message.phones]
        await self._run(stream.check, phones, kind="phones")  # refused whole before any piece is pushed
        begin = stream.end
        for piece in _pieces(phones, begin, config.piece_seconds):
            weight = (piece[-1].end - begin) * PHONE_WORK_PER_SECOND if piece else 0.0
            begin = piece[-1].end if piece else begin
            if (text := await self.service.pushes.push(stream, piece, self.scale, weight)) is not None:
                await self.ws.send_text(text)
        if message.final:
            finished = await self._run(self.service.step, stream, self.scale, stream.finish, kind="phones")
            if finished is not None:
                await self.ws.send_text(finished)
            self.phones = None
            await send_message(self.ws, EndMessage(n_frames=stream.emitted, duration=stream.end))


class PhoneSettings(NamedTuple):
    """What a phone stream's first message sets: the phone set, the model's name, the frame rate
    and the output scale (a digest of its gains, :meth:`SpeechService.scale`)."""

    language: str
    model: str
    fps: float
    scale: str


_KINDS = ("text", "chat", "phones")
"""The types of stream client message."""


PIECE_GROWTH, MAX_PIECE = 2.0, 4.0
"""A message's pieces of phones: the first covers ``piece_seconds``, each next ``PIECE_GROWTH``
times the one before, up to ``MAX_PIECE`` times ``piece_seconds``. Each piece waits for its turn
in the work pool, so a long message under load pays per piece; the first frames still come
after one short piece."""


def _pieces(phones: list[Phone], begin: float, seconds: float) -> list[list[Phone]]:
    """``phones`` in consecutive groups, the first covering at most ``seconds`` and each next
    growing as :data:`PIECE_GROWTH` says (a longer phone alone); one empty group for no phones."""
    pieces: list[list[Phone]] = [[]]
    span, longest = seconds, MAX_PIECE * seconds
    for phone in phones:
        if pieces[-1] and phone.end - begin > span:
            begin = pieces[-1][-1].end
            span = min(span * PIECE_GROWTH, longest)
            pieces.append([])
        pieces[-1].append(phone)
    return pieces
