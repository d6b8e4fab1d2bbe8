"""The vispeech web server: speak, chat and stream APIs, the web app, the avatar.

Routes (the browser contract is ``docs/web.md``; ``docs/serve.md`` describes the server):

- ``GET /api/config``; ``POST /api/speak``; ``POST /api/animate`` (an uploaded recording);
  ``GET /api/audio/<id>.wav``; ``POST /api/chat``;
- ``WebSocket /api/stream`` (text spoken clause by clause, or timed phones to frames);
- ``WebSocket /api/listen`` (live audio in, frames out);
- ``/``, ``/player``, ``/viewer`` and ``/static/...`` (the built web app),
  ``/static/face2d.js`` (the preview's 2D face), ``/avatar.glb``; OpenAPI at ``/docs``.

Every bad request gets a 4xx JSON ``{"detail": "..."}``: 422 for a malformed body, 400 for
input the library refuses (or a Host not allowed), 401 without the token (when one is
configured), 403 from a foreign Origin, 413 for a body over the limit, 415 for a form where an
audio file was wanted, 429 past the rate limit. The CPU-heavy work runs in a bounded
:class:`~vispeech.serve.pool.WorkPool`: when its queue is full the answer is 503 with
``Retry-After`` (a stream error on the WebSocket).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import sys
import threading
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

from fastapi import FastAPI, HTTPException, Query, Request, WebSocket
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.websockets import WebSocketDisconnect, WebSocketDisconnected

import vispeech
import vispeech.preview
from vispeech.alignment.phones import Phone
from vispeech.errors import VispeechError
from vispeech.frontends.audio import probe_upload
from vispeech.frontends.espeak import voices
from vispeech.motion.life import check_layers
from vispeech.serve.config import CONFIG_VARIABLE, ServeConfig
from vispeech.serve.errors import EXCEPTION_HANDLERS, REFUSALS, describe_errors
from vispeech.serve.pool import Cancelled
from vispeech.serve.safety import (
    BodySizeLimit,
    HostOriginCheck,
    TokenAuth,
    client_key,
)
from vispeech.serve.schemas import (
    MAX_TEXT_CHARS,
    AnimateQuery,
    AudioStartMessage,
    ChatRequest,
    ChatResponse,
    ClientMessage,
    ConfigResponse,
    EndMessage,
    ErrorMessage,
    ErrorResponse,
    ListenClientMessage,
    PhonesMessage,
    ServerMessage,
    SpeakRequest,
    SpeakResponse,
    StartMessage,
    TextMessage,
    WarningMessage,
)
from vispeech.serve.service import (
    AUDIO_WORK_PER_SECOND,
    MIN_CHUNK_SECONDS,
    PHONE_WORK_PER_SECOND,
    TEXT_WORK_PER_CHAR,
    SpeechService,
)
from vispeech.streaming import (
    LiveAudioStream,
    PhoneStream,
    open_phone_stream,
    speech_messages,
    split_clauses,
)

log = logging.getLogger("vispeech.serve")

STATIC_DIR = Path(__file__).parent / "static"
"""Where ``web/build.mjs`` puts the built web app."""

_PAGES = {"/": "index.html", "/player": "player.html", "/viewer": "viewer.html"}
_AUDIO_ID = re.compile(r"^[0-9a-f]{32}$")
FAST_GRACE_SECONDS = 1.0
"""Audio (seconds) a live client may send beyond ``max_audio_speed`` times real time before it is warned."""
AUDIO_TYPES = ("audio/wav", "audio/flac", "audio/mpeg", "audio/ogg", "application/octet-stream")
"""Content types ``POST /api/animate`` documents (the body's own header tells its format)."""
_FORM_TYPES = ("multipart/form-data", "application/x-www-form-urlencoded", "application/json")
_ERRORS = {code: {"model": ErrorResponse} for code in (400, 401, 403, 413, 422, 429, 503)}


def app_from_environment() -> FastAPI:
    """The application of one of several server processes, set up from :data:`CONFIG_VARIABLE`
    (uvicorn's ``factory``: each process loads its own models and shares the SQLite cache)."""
    text = os.environ.get(CONFIG_VARIABLE)
    if not text:
        raise VispeechError(f"{CONFIG_VARIABLE} is not set: start the processes with vispeech serve --processes N")
    return create_app(ServeConfig.from_json(text))


def _avatar_bytes(path: Path) -> bytes | None:
    """The head at ``path`` prepared for the page (:func:`~vispeech.motion.head.prepared_head`), or None
    (served as it is) when it cannot be: the reason is logged."""
    from vispeech.motion.rigging.head import prepared_head

    try:
        data, report = prepared_head(path)
    except VispeechError as exc:
        log.warning("serving %s as it is: %s", path, exc)
        return None
    for note in report.notes:
        log.info("avatar %s: %s", path.name, note)
    return data


def create_app(config: ServeConfig | None = None) -> FastAPI:
    """The FastAPI application serving ``config`` (defaults: see :class:`ServeConfig`)."""
    config = config or ServeConfig()
    if config.avatar is not None and not Path(config.avatar).is_file():
        raise VispeechError(f"avatar file not found: {config.avatar}")
    avatar_bytes = _avatar_bytes(Path(config.avatar)) if config.avatar is not None and config.prepare_avatar else None
    service = SpeechService(config)
    static_dir = Path(config.static_dir or STATIC_DIR)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if config.switch_interval:
            # the event loop releases the GIL for every socket call and must win it back from a worker in
            # pure Python: the default 5 ms a time would slow the loop to a crawl under load
            sys.setswitchinterval(config.switch_interval)
        await run_in_threadpool(service.warm_up)
        yield
        service.pool.close()
        service.cache.close()

    app = FastAPI(title="vispeech", version=vispeech.__version__, lifespan=lifespan,
                  description="Speech animation: text to audio and ARKit blend-shape animation.",
                  exception_handlers=EXCEPTION_HANDLERS)
    app.state.service = service
    app.add_middleware(BodySizeLimit, max_bytes=config.max_body_bytes, paths={"/api/animate": config.max_audio_bytes})
    app.add_middleware(TokenAuth, token=config.token)
    app.add_middleware(HostOriginCheck, allowed_hosts=config.allowed_hosts, allowed_origins=config.allowed_origins)

    @app.get("/api/config", response_model=ConfigResponse)
    async def get_config() -> ConfigResponse:
        """What the web app needs: avatar URL, languages, the models that speak text and those that
        animate audio, frame rate."""
        return ConfigResponse(
            avatar_url="/avatar.glb" if config.avatar is not None else None,
            avatar_credit=config.avatar_credit,
            languages=[v.language for v in sorted(voices(), key=lambda v: (v.phones == "ipa", v.language != "sv"))],
            language_names={v.language: v.name.strip() for v in voices()},
            chat_languages=service.chat_languages,
            models=[name for name, model in service.models.items() if model.input_kind == "phones"],
            audio_models=[name for name, model in service.models.items() if model.input_kind == "audio"],
            default_model=config.default_model,
            stream_model=service.stream_model,
            audio_model=service.audio_model,
            fps=config.fps,
            max_text=MAX_TEXT_CHARS,
            token_required=config.token is not None,
        )

    @app.post("/api/speak", response_model=SpeakResponse, responses=_ERRORS)
    async def post_speak(request: SpeakRequest, http: Request) -> SpeakResponse:
        """Speak ``text``: the audio's URL and the animation (served from the cache when repeated)."""
        ip = client_key(http.scope)
        service.pay(ip, service.text_cost(request.text))
        args = (request.text, request.lang, request.model, request.rate, check_layers(request.life), request.seed)
        return (await run_in_threadpool(service.lookup, *args)
                or await service.pool.run(ip, service.speak, *args, weight=len(request.text) * TEXT_WORK_PER_CHAR))

    @app.post("/api/animate", response_model=SpeakResponse, responses={**_ERRORS, 415: {"model": ErrorResponse}},
              openapi_extra={"requestBody": {"required": True, "content": {
                  kind: {"schema": {"type": "string", "format": "binary"}} for kind in AUDIO_TYPES}}})
    async def post_animate(query: Annotated[AnimateQuery, Query()], http: Request) -> SpeakResponse:
        """Animate a recording: the request body is the audio file itself (WAV, FLAC, MP3 or OGG, any
        content type but a form's), the options are query parameters; answered as ``/api/speak`` is,
        the audio URL serving the recording as WAV (from the cache when the same file came before)."""
        if http.headers.get("content-type", "").partition(";")[0].strip().lower() in _FORM_TYPES:
            raise HTTPException(415, "send the audio file itself as the request body (Content-Type audio/wav, "
                                "audio/flac, audio/mpeg, audio/ogg or application/octet-stream), not a form or JSON")
        ip = client_key(http.scope)
        service.pay(ip, 1.0)
        data = await http.body()
        digest, duration = await run_in_threadpool(probe_upload, data)
        service.bucket.charge(ip, service.audio_cost(duration) - 1.0)
        return (await run_in_threadpool(service.lookup_upload, digest, query)
                or await service.pool.run(ip, service.animate_upload, data, digest, query,
                                          weight=duration * AUDIO_WORK_PER_SECOND))

    @app.get("/api/audio/{audio_id}.wav", response_class=Response,
             responses={200: {"content": {"audio/wav": {}}}, 404: {"model": ErrorResponse}})
    def get_audio(audio_id: str) -> Response:
        """The WAV file of a spoken utterance."""
        wav = service.cache.audio(audio_id) if _AUDIO_ID.match(audio_id) else None
        if wav is None:
            raise HTTPException(404, "no such audio")
        return Response(wav, media_type="audio/wav", headers={"Cache-Control": "public, max-age=86400"})

    @app.post("/api/chat", response_model=ChatResponse, responses={**_ERRORS, 502: {"model": ErrorResponse}})
    async def post_chat(request: ChatRequest, http: Request) -> ChatResponse:
        """The chat bot's reply to ``message``, spoken unless ``speak`` is false."""
        ip = client_key(http.scope)
        service.pay(ip, service.text_cost(request.message))
        if request.speak:
            service.model(request.model)  # an unknown model is refused before the bot is asked
        reply, spoken = await run_in_threadpool(service.reply, request.message, request.lang)  # may wait on a service
        speech = None
        if request.speak:
            service.bucket.charge(ip, service.text_cost(reply))
            args = (reply, spoken, request.model, 1.0, check_layers(request.life), request.seed)
            speech = (await run_in_threadpool(service.lookup, *args)
                      or await service.pool.run(ip, service.speak, *args, weight=len(reply) * TEXT_WORK_PER_CHAR))
        return ChatResponse(reply=reply, lang=spoken, speech=speech)

    @app.websocket("/api/stream")
    async def stream(websocket: WebSocket) -> None:
        """Speech animation as it is computed (see :mod:`vispeech.streaming`)."""
        await _serve(websocket, service, _StreamConnection)

    @app.websocket("/api/listen")
    async def listen_stream(websocket: WebSocket) -> None:
        """Live audio in (16-bit PCM chunks), frames out as soon as they are computed."""
        await _serve(websocket, service, _ListenConnection)

    @app.get("/avatar.glb", include_in_schema=False)
    def avatar() -> Response:
        if config.avatar is None or not Path(config.avatar).is_file():
            return JSONResponse({"detail": "no avatar: start the server with --avatar HEAD.glb"}, status_code=404)
        if avatar_bytes is not None:
            return Response(avatar_bytes, media_type="model/gltf-binary")
        return FileResponse(config.avatar, media_type="model/gltf-binary")

    face2d = Path(vispeech.preview.__file__).parent / "face2d.js"

    @app.get("/static/face2d.js", include_in_schema=False)
    def face2d_script() -> FileResponse:
        return FileResponse(face2d, media_type="text/javascript")

    not_built = {"detail": "the web app is not built: run `npm run build` in web/"}
    for route, name in _PAGES.items():
        app.add_api_route(route, _page(static_dir / name, not_built), methods=["GET"], include_in_schema=False)
    if static_dir.is_dir():
        app.mount("/static", StaticFiles(directory=static_dir), name="static")
    else:
        @app.get("/static/{path:path}", include_in_schema=False)
        def static_missing(path: str) -> JSONResponse:
            return JSONResponse(not_built, status_code=404)

    return app


def _page(path: Path, not_built: dict):
    def page() -> Response:
        if not path.is_file():
            return JSONResponse(not_built, status_code=404)
        return FileResponse(path, media_type="text/html")

    return page


def _json(message: BaseModel | dict) -> str:
    """One server message (a model of :data:`ServerMessage`, or the engine's dict form of one) as JSON."""
    typed = message if isinstance(message, BaseModel) else ServerMessage.validate_python(message)
    return typed.model_dump_json()


async def _send(websocket: WebSocket, message: BaseModel | dict) -> None:
    await websocket.send_text(_json(message))


async def _error(websocket: WebSocket, message: str) -> None:
    await _send(websocket, ErrorMessage(message=message))


_GONE = (WebSocketDisconnect, WebSocketDisconnected, Cancelled)


async def _serve(websocket: WebSocket, service: SpeechService, kind: type[_Connection]) -> None:
    """One WebSocket connection of ``kind``: counted against the caps, served, then freed."""
    await websocket.accept()
    ip = client_key(websocket.scope)
    refusal = service.connections.open(ip)
    if refusal is not None:
        with contextlib.suppress(*_GONE, RuntimeError, OSError):
            await _error(websocket, refusal)
            await websocket.close(1013)
        return
    try:
        await kind(websocket, service, ip).serve()
    finally:
        service.connections.close(ip)


class _Connection:
    """A connection's reader (client messages into a queue, so a vanished client is seen at
    once) and processor (one message at a time, the heavy parts in the service's pool, each piece
    dropped unrun once the client has gone). Subclasses answer the messages (:meth:`_handle`)."""

    inbox_size = 4
    """Client messages read ahead of the one being answered (then TCP slows the client)."""

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        self.ws = websocket
        self.service = service
        self.config = service.config
        self.ip = ip
        self.cancelled = threading.Event()
        self.inbox: asyncio.Queue = asyncio.Queue(maxsize=self.inbox_size)

    async def serve(self) -> None:
        worker = asyncio.create_task(self._process())
        reader = asyncio.create_task(self._read())
        try:
            done, _ = await asyncio.wait({worker, reader}, timeout=self.config.stream_timeout,
                                         return_when=asyncio.FIRST_COMPLETED)
            self.cancelled.set()
            if worker not in done:
                worker.cancel()
                await asyncio.gather(worker, return_exceptions=True)
                if not done:
                    await self._close(1001, f"the connection was open {self.config.stream_timeout:g} s, the most "
                                            "allowed: closing (open a new one to go on)")
        finally:
            self.cancelled.set()
            reader.cancel()
            worker.cancel()
            await asyncio.gather(worker, reader, return_exceptions=True)
            self._release()

    def _release(self) -> None:
        """Drop what the connection holds (it has ended)."""

    async def _read(self) -> None:
        while True:
            event = await self.ws.receive()
            if event["type"] == "websocket.disconnect":
                return
            await self._enqueue(event)

    async def _enqueue(self, event: dict) -> None:
        await self.inbox.put(event)

    async def _next(self) -> dict:
        """The next client message to answer."""
        return await self.inbox.get()

    async def _close(self, code: int, message: str) -> None:
        with contextlib.suppress(*_GONE, RuntimeError, OSError):
            await _error(self.ws, message)
            await self.ws.close(code)

    async def _run(self, fn, *args, weight: float = 0.0):
        return await self.service.pool.run(self.ip, fn, *args, cancelled=self.cancelled, weight=weight)

    async def _process(self) -> None:
        try:
            while True:
                try:
                    event = await asyncio.wait_for(self._next(), self.config.idle_timeout)
                except TimeoutError:
                    await self._close(1001, f"no message for {self.config.idle_timeout:g} s: closing")
                    return
                if not await self._handle(event):
                    return
        except _GONE:
            pass
        except Exception:
            log.exception("internal error in a stream")
            await self._close(1011, "internal server error")

    async def _handle(self, event: dict) -> bool:
        """Answer one client message; ``False`` once the connection is closed."""
        raise NotImplementedError

    async def _oversize(self, event: dict) -> bool:
        """Close the connection (1009) when ``event`` is over the message size limit; whether it was."""
        limit = self.config.max_message_bytes
        raw = event.get("text")
        if raw is None:
            size = len(event.get("bytes") or b"")
        else:
            size = len(raw) if len(raw) > limit else len(raw.encode("utf-8", "replace"))
        if size <= limit:
            return False
        await self._close(1009, f"message too large (limit {limit} bytes)")
        return True


class _StreamConnection(_Connection):
    """An ``/api/stream`` connection: texts spoken clause by clause, phone streams."""

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        super().__init__(websocket, service, ip)
        self.phones: PhoneStream | None = None

    def _release(self) -> None:
        if self.phones is not None:
            self.phones.close()

    async def _handle(self, event: dict) -> bool:
        if await self._oversize(event):
            return False
        raw = event.get("text")
        if raw is None:
            await _error(self.ws, "send JSON text messages")
            return True
        try:
            message = ClientMessage.validate_json(raw)
        except ValidationError as exc:
            await _error(self.ws, describe_errors(exc.errors(), skip=1, what="message"))
            return True
        try:
            if isinstance(message, TextMessage):
                if self.phones is not None:
                    raise VispeechError('a phone stream is open: end it with "final": true first')
                self.service.pay(self.ip, self.service.text_cost(message.text))
                await self._text(message)
            else:
                await self._phones(message)
        except REFUSALS as exc:
            if self.phones is not None and self.phones.closed:
                self.phones = None
            await _error(self.ws, str(exc))
        return True

    async def _text(self, message: TextMessage) -> None:
        _, model = self.service.model(message.model, stream=True)
        messages = speech_messages(message.text, message.lang, model, fps=self.config.fps, rate=message.rate,
                                   scale=self.service.calibration, variant=self.config.voice)

        def next_clause() -> tuple[list[str], float | None] | None:
            batch = next(messages, None)
            if batch is None:
                return None
            begin = next((item["start"] for item in batch if item["type"] == "audio"), None)
            return [_json(item) for item in batch], begin

        weights = [len(clause) * TEXT_WORK_PER_CHAR for clause in split_clauses(message.text)]
        playing = None  # when the first audio chunk left: the client's playback starts no earlier
        try:
            while (batch := await self._run(next_clause, weight=weights.pop(0) if weights else 0.0)) is not None:
                texts, begin = batch
                now = time.monotonic()
                if playing is None and begin is not None:
                    playing = now - begin
                elif begin is not None and now - playing > begin:
                    late = now - playing - begin
                    await _send(self.ws, WarningMessage(
                        code="late", seconds=round(late, 3),
                        message=f"the clause at {begin:.2f} s leaves {late:.2f} s after it is due: the server is "
                                "overloaded (buffer more before playing, or try again later)"))
                for text in texts:
                    await self.ws.send_text(text)
        finally:
            with contextlib.suppress(ValueError):  # still running in its thread
                messages.close()

    async def _phones(self, message: PhonesMessage) -> None:
        """Frames for ``message``'s phones, pushed in pieces; with ``final`` the rest and ``end``."""
        config, stream = self.config, self.phones
        if stream is not None and message.lang is not None and message.lang != stream.language:
            raise VispeechError(f"this phone stream is in {stream.language}, not {message.lang}")
        begin = stream.end if stream is not None else 0.0
        last = max((p.end for p in message.phones), default=begin)
        added = max(0.0, last - begin)
        if added > config.max_message_seconds + 1e-9:
            raise VispeechError(f"a phones message may add at most {config.max_message_seconds:g} s of phones "
                                f"(this one adds {added:.1f} s): send them in smaller messages")
        if last > config.max_stream_seconds + 1e-9:
            raise VispeechError(f"a phone stream may last at most {config.max_stream_seconds:g} s "
                                f"(this message ends at {last:.1f} s)")
        self.service.pay(self.ip, max(config.min_message_cost, added / config.phone_seconds_per_token))
        if stream is None:
            name, model = self.service.model(message.model, stream=True)
            stream = await self._run(open_phone_stream, model, message.lang or "en", config.fps)
            self.phones = stream
            await _send(self.ws, StartMessage(fps=stream.fps, channels=list(stream.channels), sample_rate=None,
                                              model=name, lookahead=stream.lookahead))
        phones = [Phone(p.symbol, p.start, p.end, None, p.stress) for p in message.phones]
        await self._run(stream.check, phones)  # refused whole before any piece is pushed
        begin = stream.end
        for piece in _pieces(phones, begin, config.piece_seconds):
            weight = (piece[-1].end - begin) * PHONE_WORK_PER_SECOND if piece else 0.0
            begin = piece[-1].end if piece else begin
            if (text := await self.service.pushes.push(stream, piece, weight)) is not None:
                await self.ws.send_text(text)
        if message.final:
            if (text := await self._run(self.service.step, stream, stream.finish)) is not None:
                await self.ws.send_text(text)
            self.phones = None
            await _send(self.ws, EndMessage(n_frames=stream.emitted, duration=stream.end))


class _ListenConnection(_Connection):
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

    async def _enqueue(self, event: dict) -> None:
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
            await _error(self.ws, describe_errors(exc.errors(), skip=1, what="message", kinds=("start", "stop")))
            return True
        try:
            if isinstance(message, AudioStartMessage):
                await self._start(message)
            else:
                await self._stop()
        except REFUSALS as exc:
            await _error(self.ws, str(exc))
        return True

    async def _start(self, message: AudioStartMessage) -> None:
        if self.audio is not None:
            raise VispeechError('an audio stream is open: end it with {"type": "stop"} first')
        self.service.pay(self.ip, self.config.min_message_cost)
        name, model = self.service.model(message.model, audio=True)
        stream = await self._run(LiveAudioStream, model, message.sample_rate, message.fps or self.config.fps)
        self.audio, self.started, self.warned_fast, self.behind = stream, time.monotonic(), False, False
        await _send(self.ws, StartMessage(fps=stream.fps, channels=list(stream.channels),
                                          sample_rate=stream.sample_rate, model=name, lookahead=stream.lookahead,
                                          delay=round(stream.delay, 6)))

    async def _stop(self) -> None:
        stream = self.audio
        if stream is None:
            raise VispeechError('no audio stream is open: send {"type": "start", "sample_rate": ...} first')
        self.audio = None
        text = await self._run(self.service.step, stream, stream.finish)
        if text is not None:
            await self.ws.send_text(text)
        await _send(self.ws, EndMessage(n_frames=stream.emitted, duration=stream.duration))

    async def _audio(self, chunks: list[dict]) -> None:
        """Check the chunks, push them in one job, send their frames; warn of a client too fast or a lag."""
        stream, config = self.audio, self.config
        if stream is None:
            if not self.refusing:
                self.refusing = True
                await _error(self.ws, 'send {"type": "start", "sample_rate": ...} before audio')
            return
        pcm = []
        seconds = stream.duration
        try:
            for chunk in chunks:
                data = chunk["bytes"]
                if len(data) > config.max_chunk_bytes:
                    raise VispeechError(f"an audio chunk may have at most {config.max_chunk_bytes} bytes "
                                        f"(this one has {len(data)}): send smaller chunks")
                if len(data) % 2:
                    raise VispeechError(f"16-bit PCM has 2 bytes a sample: a chunk of {len(data)} bytes is cut short")
                added = len(data) / 2 / stream.sample_rate
                if seconds + added > config.max_stream_seconds + 1e-9:
                    raise VispeechError(f"an audio stream may last at most {config.max_stream_seconds:g} s")
                self.service.pay(self.ip, max(added, MIN_CHUNK_SECONDS) / config.audio_seconds_per_token)
                pcm.append(data)
                seconds += added
            text = await self._run(self.service.step, stream, stream.push, b"".join(pcm),
                                   weight=(seconds - stream.duration) * AUDIO_WORK_PER_SECOND)
        except REFUSALS as exc:
            stream.close()
            self.audio, self.refusing = None, True
            await _error(self.ws, f"{exc}; the audio stream has ended (send a start message to begin another)")
            return
        if text is not None:
            await self.ws.send_text(text)
        now = time.monotonic()
        lead = stream.duration - (now - self.started)
        allowed = FAST_GRACE_SECONDS + config.max_audio_speed * (now - self.started)
        if not self.warned_fast and stream.duration > allowed:
            self.warned_fast = True
            await _send(self.ws, WarningMessage(
                code="too_fast", seconds=round(lead, 3),
                message=f"audio is arriving faster than {config.max_audio_speed:g} times real time ({lead:.1f} s "
                        "ahead): frames come as fast as they are computed, not as live audio's would"))
        lag = now - chunks[0]["arrived"]
        if lag > config.max_audio_lag and not self.behind:
            self.behind = True
            await _send(self.ws, WarningMessage(
                code="behind", seconds=round(lag, 3),
                message=f"the server is {lag:.2f} s behind the audio (more than {config.max_audio_lag:g} s): "
                        "frames are late"))
        elif lag < config.max_audio_lag / 2:
            self.behind = False


def _pieces(phones: list[Phone], begin: float, seconds: float) -> list[list[Phone]]:
    """``phones`` in consecutive groups covering at most ``seconds`` each (a longer phone alone);
    one empty group for no phones."""
    pieces: list[list[Phone]] = [[]]
    for phone in phones:
        if pieces[-1] and phone.end - begin > seconds:
            begin = pieces[-1][-1].end
            pieces.append([])
        pieces[-1].append(phone)
    return pieces
