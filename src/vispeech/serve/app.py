"""The vispeech web server: speak, chat and stream APIs, the web app, the avatar.

Routes (the browser contract is ``docs/web.md``; ``docs/serve.md`` describes the server):

- ``GET /api/config``; ``POST /api/speak``; ``GET /api/audio/<id>.wav``; ``POST /api/chat``;
- ``WebSocket /api/stream`` (text spoken clause by clause, or timed phones to frames);
- ``/``, ``/player``, ``/viewer`` and ``/static/...`` (the built web app),
  ``/static/face2d.js`` (the preview's 2D face), ``/avatar.glb``; OpenAPI at ``/docs``.

Every bad request gets a 4xx JSON ``{"detail": "..."}``: 422 for a malformed body, 400 for
input the library refuses, 413 for a body over the limit, 429 past the rate limit.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.websockets import WebSocketDisconnect, WebSocketDisconnected

import vispeech
import vispeech.preview
from vispeech.alignment.phones import Phone
from vispeech.errors import VispeechError
from vispeech.frontends.espeak import VOICES
from vispeech.models.contract import Estimator
from vispeech.models.registry import PRETRAINED, RUNNABLE, load_model, pretrained_path
from vispeech.motion.jsonformat import ANIMATION_FORMAT
from vispeech.phonetics.inventory import LANGUAGES
from vispeech.pipeline import DEFAULT_FPS, DEFAULT_MODEL, GREETINGS, animate, speak
from vispeech.serve.bot import ChatBot, ChatBotError, RuleBot
from vispeech.serve.cache import CacheKey, UtteranceCache
from vispeech.serve.safety import BodySizeLimit, RateLimit, TokenBucket, client_key
from vispeech.serve.schemas import (
    MAX_TEXT_CHARS, ChatRequest, ChatResponse, ClientMessage, ConfigResponse, EndMessage, ErrorMessage,
    ErrorResponse, FramesMessage, PhonesMessage, ServerMessage, SpeakRequest, SpeakResponse, StartMessage,
    TextMessage,
)
from vispeech.streaming import PhoneStream, open_phone_stream, speech_messages

log = logging.getLogger("vispeech.serve")

STATIC_DIR = Path(__file__).parent / "static"
"""Where ``web/build.mjs`` puts the built web app."""

LOW_LATENCY_MODEL = "grid-tdnn-lowlatency"
"""The shipped low-latency network (2 frames of look-ahead): what the stream uses unless told otherwise."""

_PAGES = {"/": "index.html", "/player": "player.html", "/viewer": "viewer.html"}
_AUDIO_ID = re.compile(r"^[0-9a-f]{32}$")
_ERRORS = {code: {"model": ErrorResponse} for code in (400, 413, 422, 429)}


@dataclass
class ServeConfig:
    """Server settings.

    ``cache``: SQLite file of the utterance cache (``None``: the user cache folder,
    ``":memory:"``: none kept). ``stream_model``: model name or saved folder the stream uses
    when a message names none; ``None`` picks the shipped ``grid-tdnn-lowlatency`` if it is there and
    otherwise ``default_model``. ``rate_limit``: requests a second per client IP for speak,
    chat and stream text messages (0 = no limit), with bursts of ``burst``. Sizes are bytes.
    ``static_dir``: the built web app (default :data:`STATIC_DIR`). ``avatar_credit``: a
    line the pages show under the head (its author and licence).
    """

    avatar: Path | None = None
    avatar_credit: str | None = None
    cache: str | os.PathLike | None = None
    cache_entries: int = 10_000
    bot: ChatBot = field(default_factory=RuleBot)
    default_model: str = DEFAULT_MODEL
    stream_model: str | None = None
    fps: float = DEFAULT_FPS
    rate_limit: float = 2.0
    burst: int = 20
    max_body_bytes: int = 64 * 1024
    max_message_bytes: int = 64 * 1024
    max_streams: int = 100
    static_dir: Path | None = None


class SpeechService:
    """The models, cache and bot behind the routes (the library calls, without HTTP)."""

    def __init__(self, config: ServeConfig) -> None:
        self.config = config
        self.models: dict[str, Estimator] = {}
        self.versions: dict[str, str] = {}
        for name in RUNNABLE:
            self._add(name, load_model(name), pretrained_path(name) if name in PRETRAINED else None)
        if config.default_model not in self.models:
            raise VispeechError(f"default model {config.default_model!r} is not one of {', '.join(self.models)}")
        self.stream_model = self._choose_stream_model(config.stream_model)
        self.cache = UtteranceCache(config.cache, config.cache_entries)
        self.bucket = TokenBucket(config.rate_limit, config.burst)
        self.active_streams = 0

    def _add(self, name: str, model: Estimator, folder: Path | None = None) -> None:
        """Offer ``model`` as ``name``; its version digests its parameters (and its saved folder's files)."""
        about = {"vispeech": vispeech.__version__, "model": name, "params": model.get_params()}
        digest = hashlib.sha256(json.dumps(about, sort_keys=True, default=str).encode())
        if folder is not None:
            for path in sorted(folder.iterdir()):
                if path.is_file():
                    digest.update(path.name.encode() + path.read_bytes())
        self.models[name] = model
        self.versions[name] = digest.hexdigest()[:16]

    def _choose_stream_model(self, spec: str | None) -> str:
        if spec is None:
            if LOW_LATENCY_MODEL in self.models:
                return LOW_LATENCY_MODEL
            log.info("%s is not trained: streaming uses %s", LOW_LATENCY_MODEL, self.config.default_model)
            return self.config.default_model
        if spec in self.models:
            return spec
        model = load_model(spec)
        model.check_fitted()
        folder = Path(spec)
        name = model.name if model.name not in self.models else f"{model.name}:{folder.name}"
        self._add(name, model, folder)
        return name

    def warm_up(self) -> None:
        """Load espeak-ng's voices and run the default and stream models once, so a first request is no slower."""
        for language, text in GREETINGS.items():
            utterance = speak(text, language, model=self.models[self.config.default_model], fps=self.config.fps)
            with contextlib.suppress(VispeechError):  # a trained stream model may know one language only
                animate(utterance.phones, self.models[self.stream_model], self.config.fps)

    def model(self, name: str | None, stream: bool = False) -> tuple[str, Estimator]:
        """The model called ``name`` (``None``: the default, or the stream model when ``stream``)."""
        name = name or (self.stream_model if stream else self.config.default_model)
        if name not in self.models:
            raise VispeechError(f"unknown model {name!r} (use one of: {', '.join(self.models)})")
        return name, self.models[name]

    def speak(self, text: str, lang: str, model_name: str | None, rate: float) -> dict:
        """A :class:`SpeakResponse` as a dict, from the cache when the same request was answered before."""
        name, model = self.model(model_name)
        key = CacheKey(text, lang, VOICES[lang], float(rate), name, self.versions[name], self.config.fps)
        entry = self.cache.get(key)
        cached = entry is not None
        if entry is None:
            utterance = speak(text, lang, model=model, rate=rate, fps=self.config.fps)
            animation = {"format": ANIMATION_FORMAT, "version": 1, **utterance.track.to_dict(),
                         "phones": utterance.phones.to_dict()}
            entry = self.cache.put(key, utterance.wav_bytes(), json.dumps(animation, separators=(",", ":")))
        return {"audio_url": f"/api/audio/{entry.id}.wav", "animation": json.loads(entry.animation),
                "text": text, "cached": cached}

    def chat(self, message: str, lang: str, say: bool, model_name: str | None) -> dict:
        """A :class:`ChatResponse` as a dict: the bot's reply, spoken when ``say``."""
        reply = self.config.bot.reply(message, lang)
        if not isinstance(reply, str) or not reply.strip():
            raise ChatBotError("the chat bot gave no reply")
        reply = reply.strip()[:MAX_TEXT_CHARS]
        speech = self.speak(reply, lang, model_name, 1.0) if say else None
        return {"reply": reply, "lang": lang, "speech": speech}


def describe_errors(errors, skip: int = 0, what: str = "body") -> str:
    """Pydantic errors as one readable line: ``"text: String should have at most 1000 characters"``.

    ``skip`` leading parts of each error's location are left out; an error of the whole
    input is named ``what``.
    """
    parts = []
    for error in errors[:5]:
        loc = [str(x) for x in error.get("loc", ())[skip:] if x != "body"]
        if error.get("type") == "json_invalid":
            parts.append(f"the {what} is not valid JSON")
        elif not loc and error.get("type") in ("missing", "model_attributes_type", "dict_type", "model_type"):
            parts.append(f"the {what} must be a JSON object")
        elif error.get("type") == "union_tag_not_found":
            parts.append('"type" is missing: use "text" or "phones"')
        elif error.get("type") == "union_tag_invalid":
            parts.append(f'"type" must be "text" or "phones", not {json.dumps(error.get("ctx", {}).get("tag"))[:50]}')
        else:
            parts.append(f"{'.'.join(loc) or what}: {error.get('msg', 'invalid')}")
    return "; ".join(dict.fromkeys(parts))[:500] or "invalid request"


def create_app(config: ServeConfig | None = None) -> FastAPI:
    """The FastAPI application serving ``config`` (defaults: see :class:`ServeConfig`)."""
    config = config or ServeConfig()
    if config.avatar is not None and not Path(config.avatar).is_file():
        raise VispeechError(f"avatar file not found: {config.avatar}")
    service = SpeechService(config)
    static_dir = Path(config.static_dir or STATIC_DIR)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        await run_in_threadpool(service.warm_up)
        yield
        service.cache.close()

    app = FastAPI(title="vispeech", version=vispeech.__version__, lifespan=lifespan,
                  description="Speech animation: text to audio and ARKit blend-shape animation.")
    app.state.service = service
    app.add_middleware(BodySizeLimit, max_bytes=config.max_body_bytes)
    app.add_middleware(RateLimit, bucket=service.bucket, paths=("/api/speak", "/api/chat"))

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": describe_errors(exc.errors())}, status_code=422)

    @app.exception_handler(VispeechError)
    async def refused_input(request: Request, exc: VispeechError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=400)

    @app.exception_handler(ChatBotError)
    async def bot_failed(request: Request, exc: ChatBotError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=502)

    @app.exception_handler(Exception)
    async def internal_error(request: Request, exc: Exception) -> JSONResponse:
        log.exception("internal error on %s", request.url.path)
        return JSONResponse({"detail": "internal server error"}, status_code=500)

    @app.get("/api/config", response_model=ConfigResponse)
    def get_config() -> dict:
        """What the web app needs: avatar URL, languages, models, frame rate."""
        return {
            "avatar_url": "/avatar.glb" if config.avatar is not None else None,
            "avatar_credit": config.avatar_credit,
            "languages": list(LANGUAGES),
            "models": list(service.models),
            "default_model": config.default_model,
            "stream_model": service.stream_model,
            "fps": config.fps,
            "max_text": MAX_TEXT_CHARS,
        }

    @app.post("/api/speak", response_model=SpeakResponse, responses=_ERRORS)
    def post_speak(request: SpeakRequest) -> dict:
        """Speak ``text``: the audio's URL and the animation (served from the cache when repeated)."""
        return service.speak(request.text, request.lang, request.model, request.rate)

    @app.get("/api/audio/{audio_id}.wav", response_class=Response,
             responses={200: {"content": {"audio/wav": {}}}, 404: {"model": ErrorResponse}})
    def get_audio(audio_id: str) -> Response:
        """The WAV file of a spoken utterance."""
        wav = service.cache.audio(audio_id) if _AUDIO_ID.match(audio_id) else None
        if wav is None:
            return JSONResponse({"detail": "no such audio"}, status_code=404)
        return Response(wav, media_type="audio/wav", headers={"Cache-Control": "public, max-age=86400"})

    @app.post("/api/chat", response_model=ChatResponse, responses={**_ERRORS, 502: {"model": ErrorResponse}})
    def post_chat(request: ChatRequest) -> dict:
        """The chat bot's reply to ``message``, spoken unless ``speak`` is false."""
        return service.chat(request.message, request.lang, request.speak, request.model)

    @app.websocket("/api/stream")
    async def stream(websocket: WebSocket) -> None:
        """Speech animation as it is computed (see :mod:`vispeech.streaming`)."""
        await _serve_stream(websocket, service)

    @app.get("/avatar.glb", include_in_schema=False)
    def avatar() -> Response:
        if config.avatar is None or not Path(config.avatar).is_file():
            return JSONResponse({"detail": "no avatar: start the server with --avatar HEAD.glb"}, status_code=404)
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


async def _send(websocket: WebSocket, message: BaseModel | dict) -> None:
    """Send one server message (a model of :data:`ServerMessage`, or the engine's dict form of one)."""
    typed = message if isinstance(message, BaseModel) else ServerMessage.validate_python(message)
    await websocket.send_text(typed.model_dump_json())


async def _error(websocket: WebSocket, message: str) -> None:
    await _send(websocket, ErrorMessage(message=message))


async def _serve_stream(websocket: WebSocket, service: SpeechService) -> None:
    """One ``/api/stream`` connection: messages in order, errors answered and the connection kept."""
    await websocket.accept()
    limit = service.config.max_message_bytes
    if service.active_streams >= service.config.max_streams:
        await _error(websocket, "server busy: too many streams, try again later")
        await websocket.close(1013)
        return
    service.active_streams += 1
    phones: PhoneStream | None = None
    try:
        while True:
            event = await websocket.receive()
            if event["type"] == "websocket.disconnect":
                return
            raw = event.get("text")
            if raw is None:
                if len(event.get("bytes") or b"") > limit:
                    await _error(websocket, f"message too large (limit {limit} bytes)")
                    await websocket.close(1009)
                    return
                await _error(websocket, "send JSON text messages")
                continue
            if len(raw) > limit or len(raw.encode("utf-8", "replace")) > limit:
                await _error(websocket, f"message too large (limit {limit} bytes)")
                await websocket.close(1009)
                return
            try:
                message = ClientMessage.validate_json(raw)
            except ValidationError as exc:
                await _error(websocket, describe_errors(exc.errors(), skip=1, what="message"))
                continue
            try:
                if isinstance(message, TextMessage):
                    if phones is not None:
                        raise VispeechError('a phone stream is open: end it with "final": true first')
                    if not service.bucket.take(client_key(websocket.scope)):
                        raise VispeechError(service.bucket.message())
                    await _stream_text(websocket, service, message)
                else:
                    if phones is None:
                        phones = await _open_phone_stream(websocket, service, message)
                    if await _stream_phones(websocket, phones, message):
                        phones = None
            except VispeechError as exc:
                if phones is not None and phones.closed:
                    phones = None
                await _error(websocket, str(exc))
    except (WebSocketDisconnect, WebSocketDisconnected):
        pass
    except Exception:
        log.exception("internal error in a stream")
        try:
            await _error(websocket, "internal server error")
            await websocket.close(1011)
        except (WebSocketDisconnect, WebSocketDisconnected, RuntimeError):
            pass
    finally:
        service.active_streams -= 1
        if phones is not None:
            phones.close()


async def _stream_text(websocket: WebSocket, service: SpeechService, message: TextMessage) -> None:
    _, model = service.model(message.model, stream=True)
    messages = speech_messages(message.text, message.lang, model, fps=service.config.fps, rate=message.rate)
    try:
        while (batch := await run_in_threadpool(next, messages, None)) is not None:
            for item in batch:
                await _send(websocket, item)
    finally:
        with contextlib.suppress(ValueError):  # still running in its thread when the task was cancelled
            messages.close()


async def _open_phone_stream(websocket: WebSocket, service: SpeechService, message: PhonesMessage) -> PhoneStream:
    name, model = service.model(message.model, stream=True)
    stream = await run_in_threadpool(open_phone_stream, model, message.lang or "en", service.config.fps)
    await _send(websocket, StartMessage(fps=stream.fps, channels=list(stream.channels), sample_rate=None,
                                        model=name, lookahead=stream.lookahead))
    return stream


async def _stream_phones(websocket: WebSocket, stream: PhoneStream, message: PhonesMessage) -> bool:
    """Send the frames ``message``'s phones make ready; with ``final`` end the stream and return ``True``."""
    if message.lang is not None and message.lang != stream.language:
        raise VispeechError(f"this phone stream is in {stream.language}, not {message.lang}")
    phones = [Phone(p.symbol, p.start, p.end, None, p.stress) for p in message.phones]
    results = [await run_in_threadpool(stream.push, phones)]
    if message.final:
        results.append(await run_in_threadpool(stream.finish))
    for start, rows in results:
        if len(rows):
            await _send(websocket, FramesMessage(start_frame=start, frames=rows.round(6).tolist()))
    if message.final:
        await _send(websocket, EndMessage(n_frames=stream.emitted, duration=stream.end))
    return message.final
