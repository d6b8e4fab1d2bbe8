"""``/api/listen``: live audio in (16-bit PCM chunks), with a voice service's timings when it has
them, frames out as soon as they are computed; barge-in cancels a stream at once."""

from __future__ import annotations

import asyncio
import time

from fastapi import APIRouter, WebSocket
from pydantic import ValidationError
from starlette.types import Message

from vispeech.alignment.phones import Word
from vispeech.errors import VispeechError
from vispeech.motion.rigging.calibration import Calibration
from vispeech.realtime import TimedSpeechStream
from vispeech.serve.connection import Connection, send_error, send_message, serve_connection
from vispeech.serve.dependencies import Service
from vispeech.serve.errors import REFUSALS, describe_errors
from vispeech.serve.schemas import (
    LISTEN_MESSAGE_TYPES,
    AudioStartMessage,
    AudioStopMessage,
    CancelledMessage,
    CancelMessage,
    CharactersMessage,
    EndMessage,
    ListenClientMessage,
    StartMessage,
    VisemesMessage,
    WarningMessage,
    WordsMessage,
)
from vispeech.serve.service import (
    AUDIO_WORK_PER_SECOND,
    MIN_CHUNK_SECONDS,
    PHONE_WORK_PER_SECOND,
    SpeechService,
    scaled,
)
from vispeech.streaming import LiveAudioStream

Timings = CharactersMessage | WordsMessage | VisemesMessage

FAST_GRACE_SECONDS = 1.0
"""Audio (seconds) a live client may send beyond ``max_audio_speed`` times real time before it is warned."""

router = APIRouter()


@router.websocket("/api/listen")
async def listen_stream(websocket: WebSocket, service: Service) -> None:
    """Live audio in (16-bit PCM chunks), frames out as soon as they are computed."""
    await serve_connection(websocket, service, ListenConnection)


class ListenConnection(Connection):
    """An ``/api/listen`` connection: live audio streams, one at a time, animated by an audio
    model or, with timings, by a phone model (:class:`~vispeech.realtime.TimedSpeechStream`).

    The reader takes audio chunks as they come (up to ``max_audio_backlog`` seconds waiting, so
    a lag is seen, not hidden in TCP buffers); the processor pushes all the chunks waiting at
    once, so a session that fell behind catches up in larger steps, and the pushes of all the
    sessions waiting run together in one pool job (the service's ``listens``
    :class:`~vispeech.serve.service.PushBatcher`). Any refused
    chunk ends the audio stream (its frames would no longer line up with the client's audio);
    further chunks and timings are dropped until the next start, stop or cancel. The reader
    counts the cancels it reads (:attr:`epoch`): the chunks and timings read before a cancel are
    dropped unanswered when their turn comes.
    """

    inbox_size = 512
    kind = "listen"

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        super().__init__(websocket, service, ip)
        self.audio: LiveAudioStream | TimedSpeechStream | None = None
        self.started = 0.0
        """``time.monotonic()`` of the stream's start message."""
        self.refusing = False
        """Chunks are dropped unanswered (their error has been sent) until the next text message."""
        self.warned_fast = False
        self.behind = False
        self.waiting_bytes = 0
        self.room = asyncio.Event()
        self.held: dict | None = None
        self.epoch = 0
        """Cancel messages read so far: an event read before the last of them is stale."""
        self.last: LiveAudioStream | TimedSpeechStream | None = None
        """The stream that ended last (a cancel may still ease its face to rest), until the next start."""
        self.scale: Calibration | None = None
        """The output scale of the open stream (and of the last)."""

    def _release(self) -> None:
        if self.audio is not None:
            self.audio.close()

    def _backlog_bytes(self) -> int:
        rate = self.audio.sample_rate if self.audio is not None else 16_000
        return max(self.config.max_chunk_bytes, round(self.config.max_audio_backlog * rate * 2))

    async def _enqueue(self, event: Message) -> None:
        if _is_cancel(event.get("text")):
            self.epoch += 1
        event["epoch"] = self.epoch
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
            fresh = [chunk for chunk in event["chunks"] if chunk["epoch"] == self.epoch]
            if fresh:
                await self._audio(fresh)
            return True
        if await self._oversize(event):
            return False
        try:
            message = ListenClientMessage.validate_json(event["text"])
        except ValidationError as exc:
            await send_error(self.ws, describe_errors(exc.errors(), skip=1, what="message", kinds=LISTEN_MESSAGE_TYPES))
            return True
        timings = isinstance(message, (CharactersMessage, WordsMessage, VisemesMessage))
        if timings and (self.refusing or event["epoch"] < self.epoch):
            return True  # after a refused chunk, or before a cancel: dropped
        self.refusing = False
        try:
            if isinstance(message, AudioStartMessage):
                await self._start(message)
            elif isinstance(message, AudioStopMessage):
                await self._stop()
            elif isinstance(message, CancelMessage):
                await self._cancel(message.frame)
            else:
                await self._timings(message)
            self._worked()
        except REFUSALS as exc:
            await send_error(self.ws, str(exc))
        return True

    async def _start(self, message: AudioStartMessage) -> None:
        if self.audio is not None:
            raise VispeechError('an audio stream is open: end it with {"type": "stop"} first')
        self.service.pay(self.ip, self.config.min_message_cost)
        fps = message.fps or self.config.fps
        stream: LiveAudioStream | TimedSpeechStream
        if message.timings is None:
            name, model = self.service.model(message.model, audio=True)
            stream = await self._run(LiveAudioStream, model, message.sample_rate, fps)
        else:
            name, model = self.service.model(message.model, stream=True)
            stream = await self._run(
                TimedSpeechStream, model, message.timings, message.sample_rate, message.language, fps
            )
        self.audio, self.last, self.started = stream, None, time.monotonic()
        self.scale = self.service.scale(message.scale)[1]
        self.warned_fast = self.behind = False
        delay = round(stream.delay, 6) if isinstance(stream, LiveAudioStream) else None
        await send_message(
            self.ws,
            StartMessage(
                fps=stream.fps,
                channels=list(stream.channels),
                sample_rate=stream.sample_rate,
                model=name,
                lookahead=stream.lookahead,
                delay=delay,
            ),
        )

    async def _timings(self, message: Timings) -> None:
        """Frames for the next timings of a timed stream (refused whole, the stream going on)."""
        stream = self.audio
        if stream is None:
            raise VispeechError('no audio stream is open: send {"type": "start", "sample_rate": ...} first')
        if not isinstance(stream, TimedSpeechStream):
            raise VispeechError(f'this audio stream takes no timings: start one with "timings": "{message.type}"')
        call: tuple
        if isinstance(message, CharactersMessage):
            times = message.character_end_times_seconds
            call = (stream.add_characters, message.characters, message.character_start_times_seconds, times)
        elif isinstance(message, WordsMessage):
            times = [word.end for word in message.words]
            call = (stream.add_words, [Word(word.text, word.start, word.end) for word in message.words])
        else:
            times = [viseme.time for viseme in message.visemes]
            call = (stream.add_visemes, [(viseme.viseme, viseme.time) for viseme in message.visemes])
        config = self.config
        last = max(times, default=0.0)
        if last > config.max_stream_seconds + 1e-9:
            raise VispeechError(f"an audio stream may last at most {config.max_stream_seconds:g} s")
        # seconds of frames the message asks for past what the timings or the audio already reach: priced as phones
        added = max(0.0, last - max(stream.end, stream.duration))
        if added > config.max_message_seconds + 1e-9:
            raise VispeechError(
                f"a timings message may add at most {config.max_message_seconds:g} s "
                f"(this one adds {added:.1f} s): send them in smaller messages"
            )
        self.service.pay(self.ip, max(config.min_message_cost, added / config.phone_seconds_per_token))
        weight = added * PHONE_WORK_PER_SECOND
        text = await self._run(self.service.step, stream, self.scale, *call, weight=weight)
        if text is not None:
            await self.ws.send_text(text)

    async def _cancel(self, frame: int | None) -> None:
        """End the latest stream at once with the frames easing the face to rest from ``frame`` (barge-in)."""
        stream = self.audio or self.last
        self.audio = self.last = None
        if stream is None:
            await send_message(self.ws, CancelledMessage(start_frame=0, frames=[], n_frames=0, duration=0.0))
            return
        start, rows = stream.cancel(frame)
        frames = scaled(rows, stream, self.scale).round(6).tolist()
        await send_message(
            self.ws,
            CancelledMessage(
                start_frame=start, frames=frames, n_frames=start + len(frames), duration=round(stream.duration, 6)
            ),
        )

    async def _stop(self) -> None:
        stream = self.audio
        if stream is None:
            raise VispeechError('no audio stream is open: send {"type": "start", "sample_rate": ...} first')
        self.audio, self.last = None, stream
        text = await self._run(self.service.step, stream, self.scale, stream.finish)
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
            if isinstance(stream, TimedSpeechStream):  # counted, not heard: no work to queue
                text = self.service.step(stream, self.scale, stream.push, b"".join(pcm))
            else:
                weight = (seconds - stream.duration) * AUDIO_WORK_PER_SECOND
                text = await self.service.listens.push(stream, b"".join(pcm), self.scale, weight)
        except REFUSALS as exc:
            stream.close()
            self.audio, self.last, self.refusing = None, stream, True
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


def _is_cancel(text: str | None) -> bool:
    """Whether a client text message is a valid cancel (the reader's look, before the processor's)."""
    if text is None or '"cancel"' not in text or len(text) > 200:
        return False
    try:
        CancelMessage.model_validate_json(text)  # {"type": "cancel"} with or without its frame
    except ValidationError:
        return False
    return True
