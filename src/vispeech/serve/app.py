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

import logging
import os
import re
import sys
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

import vispeech
import vispeech.preview
from vispeech.errors import VispeechError
from vispeech.frontends.audio import probe_upload
from vispeech.frontends.espeak import voices
from vispeech.motion.life import check_layers
from vispeech.serve import listen, stream
from vispeech.serve.config import CONFIG_VARIABLE, ServeConfig
from vispeech.serve.errors import EXCEPTION_HANDLERS
from vispeech.serve.safety import (
    BodySizeLimit,
    HostOriginCheck,
    TokenAuth,
    client_key,
)
from vispeech.serve.schemas import (
    MAX_TEXT_CHARS,
    AnimateQuery,
    ChatRequest,
    ChatResponse,
    ConfigResponse,
    ErrorResponse,
    SpeakRequest,
    SpeakResponse,
)
from vispeech.serve.service import (
    AUDIO_WORK_PER_SECOND,
    TEXT_WORK_PER_CHAR,
    SpeechService,
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

    @app.get("/avatar.glb", include_in_schema=False)
    def avatar() -> Response:
        if config.avatar is None or not Path(config.avatar).is_file():
            return JSONResponse({"detail": "no avatar: start the server with --avatar HEAD.glb"}, status_code=404)
        if avatar_bytes is not None:
            return Response(avatar_bytes, media_type="model/gltf-binary")
        return FileResponse(config.avatar, media_type="model/gltf-binary")

    app.include_router(stream.router)
    app.include_router(listen.router)

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
