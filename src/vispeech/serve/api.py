"""The HTTP API: ``GET /api/config``, ``POST /api/speak``, ``POST /api/animate`` (an uploaded
recording), ``GET /api/audio/<id>.wav`` and ``POST /api/chat``."""

from __future__ import annotations

import re
from collections import Counter
from typing import Annotated, Any, get_origin

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import Response
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from vispeech.frontends.audio import probe_upload
from vispeech.frontends.espeak import languages
from vispeech.serve.bot import ChatBotError
from vispeech.serve.dependencies import ClientIP, Service
from vispeech.serve.schemas import (
    MAX_TEXT_CHARS,
    AnimateQuery,
    ChatRequest,
    ChatResponse,
    ConfigResponse,
    ErrorResponse,
    SpeakRequest,
    SpeakResponse,
    SpeechOptions,
)
from vispeech.serve.service import AUDIO_WORK_PER_SECOND, TEXT_WORK_PER_CHAR, Said, SpeechService

AUDIO_TYPES = ("audio/wav", "audio/flac", "audio/mpeg", "audio/ogg", "application/octet-stream")
"""Content types ``POST /api/animate`` documents (the body's own header tells its format)."""
_FORM = "multipart/form-data"
"""A form (``curl -F file=@FILE``, a browser's file input): the file is its part ``file``, the
options may be its fields. (``curl --data-binary @file`` says ``application/x-www-form-urlencoded``
of the file's bytes: taken as the file.)"""
_FILE_PART = "file"
_AUDIO_ID = re.compile(r"^[0-9a-f]{32}$")
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (400, 401, 403, 413, 422, 429, 503)
}
_FORM_SCHEMA = {
    "type": "object",
    "required": [_FILE_PART],
    "properties": {_FILE_PART: {"type": "string", "format": "binary"}}
    | {name: {"type": "string"} for name in AnimateQuery.model_fields},
}
_AUDIO_BODY = {
    "requestBody": {
        "required": True,
        "content": {kind: {"schema": {"type": "string", "format": "binary"}} for kind in AUDIO_TYPES}
        | {_FORM: {"schema": _FORM_SCHEMA}},
    }
}

router = APIRouter(prefix="/api")


@router.get("/config")
async def get_config(service: Service) -> ConfigResponse:
    """What the web app needs: avatar URL, languages, the models that speak text and those that
    animate audio, frame rate."""
    config = service.config
    return ConfigResponse(
        avatar_url=config.avatar_link or ("/avatar.glb" if config.head_file is not None else None),
        avatar_credit=config.head_credit,
        languages=[v.code for v in sorted(languages(), key=lambda v: (v.phones == "ipa", v.code != "sv"))],
        language_names={v.code: v.name.strip() for v in languages()},
        chat_languages=service.chat_languages,
        models=[name for name, model in service.models.items() if model.input_kind == "phones"],
        audio_models=[name for name, model in service.models.items() if model.input_kind == "audio"],
        default_model=service.default_model,
        stream_model=service.stream_model,
        audio_model=service.audio_model,
        fps=config.fps,
        max_text=MAX_TEXT_CHARS,
        token_required=config.token is not None,
    )


@router.post("/speak", responses=_ERRORS)
async def post_speak(request: SpeakRequest, service: Service, ip: ClientIP) -> SpeakResponse:
    """Speak ``text`` with the request's options: the audio's URL and the animation (served from
    the cache when repeated)."""
    service.pay(ip, service.text_cost(request.text))
    return await _spoken(service, ip, request.text, request, "speak")


@router.post("/animate", responses={**_ERRORS, 415: {"model": ErrorResponse}}, openapi_extra=_AUDIO_BODY)
async def post_animate(
    query: Annotated[AnimateQuery, Query()], http: Request, service: Service, ip: ClientIP
) -> SpeakResponse:
    """Animate a recording: the request body is the audio file itself (WAV, FLAC, MP3 or OGG, any
    content type but JSON) with the options as query parameters, or a multipart form whose part
    ``file`` is the audio file and whose other fields may set the options; answered as
    ``/api/speak`` is, the audio URL serving the recording as WAV (from the cache when the same
    file came before)."""
    kind = http.headers.get("content-type", "").partition(";")[0].strip().lower()
    if kind == "application/json":
        raise HTTPException(
            415,
            "send the audio file itself as the request body (Content-Type audio/wav, audio/flac, audio/mpeg, "
            "audio/ogg or application/octet-stream; curl --data-binary @FILE) or as the part 'file' of a "
            "multipart form (curl -F file=@FILE), not JSON",
        )
    service.pay(ip, 1.0)
    if kind == _FORM:
        data, query = await _form_upload(http, query)
    else:
        data = await http.body()
    digest, duration = await run_in_threadpool(probe_upload, data)
    service.bucket.charge(ip, service.audio_cost(duration) - 1.0)
    cached = await run_in_threadpool(service.lookup_upload, digest, query)
    if cached is not None:
        return cached
    return await service.pool.run(
        "upload", ip, service.animate_upload, data, digest, query, weight=duration * AUDIO_WORK_PER_SECOND
    )


async def _form_upload(http: Request, query: AnimateQuery) -> tuple[bytes, AnimateQuery]:
    """The audio file of a multipart form (its part ``file``) and the options: the query's, with
    the form's fields in place of those it names. A field the query does not take is a 422."""
    fields = AnimateQuery.model_fields
    lists = {name for name, field in fields.items() if get_origin(field.annotation) is list}
    async with http.form(max_files=1, max_fields=len(fields) + 3 * len(lists)) as form:
        upload = form.get(_FILE_PART)
        if not isinstance(upload, UploadFile):
            raise HTTPException(
                422, f"the form has no audio file: send it as the part '{_FILE_PART}' (curl -F file=@FILE)"
            )
        options = {name: form.getlist(name) if name in lists else form[name] for name in form if name != _FILE_PART}
        unknown = [name for name in options if name not in fields]
        if unknown:
            raise RequestValidationError([{"type": "extra_forbidden", "loc": (name,)} for name in unknown])
        try:
            query = AnimateQuery.model_validate(query.model_dump(exclude_unset=True) | options)
        except ValidationError as exc:
            raise RequestValidationError(exc.errors()) from None
        return await upload.read(), query


@router.get(
    "/audio/{audio_id}.wav",
    response_class=Response,
    responses={200: {"content": {"audio/wav": {}}}, 404: {"model": ErrorResponse}},
)
def get_audio(audio_id: str, service: Service) -> Response:
    """The WAV file of a spoken utterance."""
    wav = service.cache.audio(audio_id) if _AUDIO_ID.match(audio_id) else None
    if wav is None:
        raise HTTPException(404, "no such audio")
    return Response(wav, media_type="audio/wav", headers={"Cache-Control": "public, max-age=86400"})


@router.post("/chat", responses={**_ERRORS, **{code: {"model": ErrorResponse} for code in (404, 502, 504)}})
async def post_chat(request: ChatRequest, service: Service, ip: ClientIP) -> ChatResponse:
    """The chat bot's reply to ``message`` in ``session`` (``null``: a new one), spoken unless
    ``speak`` is false: each sentence in its own language, as the stream's chat message speaks it
    (a reply in one language is spoken whole)."""
    service.pay(ip, service.text_cost(request.message))
    if request.speak:
        service.model(request.model)  # an unknown model is refused before the bot is asked
    session = service.chats.open(request.session)
    clauses = [clause async for clause in service.chat(request.message, request.language, session)]
    if not clauses:
        raise ChatBotError("the chat bot's reply has nothing to say")
    reply = " ".join(clause.text for clause in clauses)
    amounts: Counter[str] = Counter()
    for clause in clauses:
        amounts[clause.language] += len(clause.spoken)
    spoken = amounts.most_common(1)[0][0]
    speech = None
    if request.speak:
        service.bucket.charge(ip, service.text_cost(reply))
        said: Said = reply if len(amounts) == 1 else clauses
        speech = await _spoken(service, ip, said, request.model_copy(update={"language": spoken}), "chat")
    return ChatResponse(reply=reply, language=spoken, session=session, speech=speech)


async def _spoken(service: SpeechService, ip: str, said: Said, options: SpeechOptions, kind: str) -> SpeakResponse:
    """:meth:`SpeechService.speak` of ``said`` with ``options``: from the cache at once when it is
    there, else in the work pool (a job of ``ip``'s of ``kind``)."""
    cached = await run_in_threadpool(service.lookup, said, options)
    if cached is not None:
        return cached
    chars = len(said) if isinstance(said, str) else sum(len(clause.spoken) for clause in said)
    return await service.pool.run(kind, ip, service.speak, said, options, weight=chars * TEXT_WORK_PER_CHAR)
