"""``/api/listen``: live audio in (16-bit PCM chunks), frames out as soon as they are computed."""

from __future__ import annotations

import asyncio
import time

from fastapi import APIRouter, WebSocket
from pydantic import ValidationError
from starlette.types import Message

from vispeech.errors import VispeechError
from vispeech.serve.connection import Connection, send_error, send_message, serve_connection
from vispeech.serve.dependencies import Service
from vispeech.serve.errors import REFUSALS, describe_errors
from vispeech.serve.schemas import AudioStartMessage, EndMessage, ListenClientMessage, StartMessage, WarningMessage
from vispeech.serve.service import AUDIO_WORK_PER_SECOND, MIN_CHUNK_SECONDS, SpeechService
from vispeech.streaming import LiveAudioStream

FAST_GRACE_SECONDS = 1.0
"""Audio (seconds) a live client may send beyond ``max_audio_speed`` times real time before it is warned."""

router = APIRouter()


@router.websocket("/api/listen")
async def listen_stream(websocket: WebSocket, service: Service) -> None:
    """Live audio in (16-bit PCM chunks), frames out as soon as they are computed."""
    await serve_connection(websocket, service, ListenConnection)


class ListenConnection(Connection):
    """An ``/api/listen`` connection: live audio streams, one at a time.

    The reader takes audio chunks as they come (up to ``max_audio_backlog`` seconds waiting, so
    a lag is seen, not hidden in TCP buffers); the processor pushes all the chunks waiting at
    once in one pool job, so a session that fell behind catches up in larger steps. Any refused
    chunk ends the audio stream (its frames would no longer line up with the client's audio);
    further chunks are dropped until the next text message.
    """

    inbox_size = 512

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        super().__init__(websocket, service, ip)
        self.audio: LiveAudioStream | None = None
        self.started = 0.0
        """``time.monotonic()`` of the stream's start message."""
        self.refusing = False
        """Chunks are dropped unanswered (their error has been sent) until the next text message."""
        self.warned_fast = False
        self.behind = False
        self.waiting_bytes = 0
        self.room = asyncio.Event()
        self.held: dict | None = None

    def _release(self) -> None:
        if self.audio is not None:
            self.audio.close()

    def _backlog_bytes(self) -> int:
        rate = self.audio.sample_rate if self.audio is not None else 16_000
        return max(self.config.max_chunk_bytes, round(self.config.max_audio_backlog * rate * 2))

    async def _enqueue(self, event: Message) -> None:
        size = len(event.get("bytes") or event.get("text") or "")
        while self.waiting_bytes and self.waiting_bytes + size > self._backlog_bytes():
            self.room.clear()
            await self.room.wait()
        event["arrived"] = time.monotonic()
        self.waiting_bytes += size
        await self.inbox.put(event)

    def _taken(self, event: dict) -> dict:
        self.waiting_bytes -= len(event.get("bytes") or event.get("text") or "")
        self.room.set()
        return event

    async def _next(self) -> dict:
        """The next text message, or all the audio chunks waiting as one ``{"chunks": [...]}``."""
        event = self.held or self._taken(await self.inbox.get())
        self.held = None
        if event.get("bytes") is None:
            return event
        chunks = [event]
        while not self.inbox.empty():
            event = self._taken(self.inbox.get_nowait())
            if event.get("bytes") is None:
                self.held = event
                break
            chunks.append(event)
        return {"chunks": chunks}

    async def _handle(self, event: dict) -> bool:
        if "chunks" in event:
            for chunk in event["chunks"]:
                if await self._oversize(chunk):
                    return False
            await self._audio(event["chunks"])
            return True
        if await self._oversize(event):
            return False
        self.refusing = False
        try:
            message = ListenClientMessage.validate_json(event["text"])
        except ValidationError as exc:
            await send_error(self.ws, describe_errors(exc.errors(), skip=1, what="message", kinds=("start", "stop")))
            return True
        try:
            if isinstance(message, AudioStartMessage):
                await self._start(message)
            else:
                await self._stop()
            self._worked()
        except REFUSALS as exc:
            await send_error(self.ws, str(exc))
        return True

    async def _start(self, message: AudioStartMessage) -> None:
        if self.audio is not None:
            raise VispeechError('an audio stream is open: end it with {"type": "stop"} first')
        self.service.pay(self.ip, self.config.min_message_cost)
        name, model = self.service.model(message.model, audio=True)
        stream = await self._run(LiveAudioStream, model, message.sample_rate, message.fps or self.config.fps)
        self.audio, self.started, self.warned_fast, self.behind = stream, time.monotonic(), False, False
        await send_message(
            self.ws,
            StartMessage(
                fps=stream.fps,
                channels=list(stream.channels),
                sample_rate=stream.sample_rate,
                model=name,
                lookahead=stream.lookahead,
                delay=round(stream.delay, 6),
            ),
        )

    async def _stop(self) -> None:
        stream = self.audio
        if stream is None:
            raise VispeechError('no audio stream is open: send {"type": "start", "sample_rate": ...} first')
        self.audio = None
        text = await self._run(self.service.step, stream, stream.finish)
        if text is not None:
            await self.ws.send_text(text)
        await send_message(self.ws, EndMessage(n_frames=stream.emitted, duration=stream.duration))

    async def _audio(self, chunks: list[dict]) -> None:
        """Check the chunks, push them in one job, send their frames; warn of a client too fast or a lag."""
        stream, config = self.audio, self.config
        if stream is None:
            if not self.refusing:
                self.refusing = True
                await send_error(self.ws, 'send {"type": "start", "sample_rate": ...} before audio')
            return
        pcm = []
        seconds = stream.duration
        try:
            for chunk in chunks:
                data = chunk["bytes"]
                if len(data) > config.max_chunk_bytes:
                    raise VispeechError(
                        f"an audio chunk may have at most {config.max_chunk_bytes} bytes "
                        f"(this one has {len(data)}): send smaller chunks"
                    )
                if len(data) % 2:
                    raise VispeechError(f"16-bit PCM has 2 bytes a sample: a chunk of {len(data)} bytes is cut short")
                added = len(data) / 2 / stream.sample_rate
                if seconds + added > config.max_stream_seconds + 1e-9:
                    raise VispeechError(f"an audio stream may last at most {config.max_stream_seconds:g} s")
                self.service.pay(self.ip, max(added, MIN_CHUNK_SECONDS) / config.audio_seconds_per_token)
                pcm.append(data)
                seconds += added
            text = await self._run(
                self.service.step,
                stream,
                stream.push,
                b"".join(pcm),
                weight=(seconds - stream.duration) * AUDIO_WORK_PER_SECOND,
            )
        except REFUSALS as exc:
            stream.close()
            self.audio, self.refusing = None, True
            await send_error(self.ws, f"{exc}; the audio stream has ended (send a start message to begin another)")
            return
        self._worked()
        if text is not None:
            await self.ws.send_text(text)
        now = time.monotonic()
        lead = stream.duration - (now - self.started)
        allowed = FAST_GRACE_SECONDS + config.max_audio_speed * (now - self.started)
        if not self.warned_fast and stream.duration > allowed:
            self.warned_fast = True
            await send_message(
                self.ws,
                WarningMessage(
                    code="too_fast",
                    seconds=round(lead, 3),
                    message=f"audio is arriving faster than {config.max_audio_speed:g} times real time ({lead:.1f} s "
                    "ahead): frames come as fast as they are computed, not as live audio's would",
                ),
            )
        lag = now - chunks[0]["arrived"]
        if lag > config.max_audio_lag and not self.behind:
            self.behind = True
            await send_message(
                self.ws,
                WarningMessage(
                    code="behind",
                    seconds=round(lag, 3),
                    message=f"the server is {lag:.2f} s behind the audio (more than {config.max_audio_lag:g} s): "
                    "frames are late",
                ),
            )
        elif lag < config.max_audio_lag / 2:
            self.behind = False
