"""The server's answers to errors, in one place: the HTTP status of each error a route raises, and
the refusals a WebSocket answers with an ``error`` message (the connection staying open)."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Coroutine, Sequence
from typing import Any

from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from vispeech.errors import NativeFailure, VispeechError
from vispeech.serve.bot import ChatBotError, ChatBotTimeout
from vispeech.serve.pool import Busy, Cancelled
from vispeech.serve.safety import RateLimited
from vispeech.serve.sessions import UnknownSession

log = logging.getLogger("vispeech.serve")

Handler = Callable[[Request, Any], Coroutine[Any, Any, Response]]
"""An exception handler, as FastAPI takes it."""

REFUSALS = (VispeechError, RateLimited, Busy, ChatBotError, UnknownSession)
"""The errors a stream message is refused with: the client gets an ``error`` message and may go on."""


def describe_errors(
    errors: Sequence[Any], skip: int = 0, what: str = "body", kinds: tuple[str, ...] = ("text", "phones")
) -> str:
    """Pydantic errors as one readable line: ``"text: String should have at most 1000 characters"``.

    ``skip`` leading parts of each error's location are left out; an error of the whole
    input is named ``what``; ``kinds`` are the message types a ``"type"`` may name.
    """
    choices = " or ".join(f'"{kind}"' for kind in kinds)
    parts = []
    for error in errors[:5]:
        loc = [str(x) for x in error.get("loc", ())[skip:] if x not in ("body", "query")]
        if error.get("type") == "json_invalid":
            parts.append(f"the {what} is not valid JSON")
        elif not loc and error.get("type") in ("missing", "model_attributes_type", "dict_type", "model_type"):
            parts.append(f"the {what} must be a JSON object")
        elif error.get("type") == "union_tag_not_found":
            parts.append(f'"type" is missing: use {choices}')
        elif error.get("type") == "extra_forbidden":
            parts.append(f"unknown field {'.'.join(loc)!r}")
        elif error.get("type") == "union_tag_invalid":
            parts.append(f'"type" must be {choices}, not {json.dumps(error.get("ctx", {}).get("tag"))[:50]}')
        else:
            parts.append(f"{'.'.join(loc) or what}: {error.get('msg', 'invalid')}")
    return "; ".join(dict.fromkeys(parts))[:500] or "invalid request"


def _answer(status: int) -> Handler:
    """A handler that answers ``status`` with the error's message (and its ``retry_after``, if it has one)."""

    async def handler(request: Request, exc: Exception) -> JSONResponse:
        retry_after = getattr(exc, "retry_after", None)
        headers = None if retry_after is None else {"Retry-After": str(retry_after)}
        return JSONResponse({"detail": str(exc)}, status_code=status, headers=headers)

    return handler


async def _invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
    return JSONResponse({"detail": describe_errors(exc.errors())}, status_code=422)


_BODY_NOT_PARSED = "There was an error parsing the body"
"""FastAPI's 400 for a JSON body its parser gave up on by other than a syntax error (nesting
deeper than Python recurses, an integer of thousands of digits, bytes that are not UTF-8)."""


async def _http_error(request: Request, exc: HTTPException) -> Response:
    """FastAPI's own answer, but a body FastAPI could not parse is the 422 of any invalid JSON."""
    if exc.status_code == 400 and exc.detail == _BODY_NOT_PARSED:
        return JSONResponse({"detail": "the body is not valid JSON"}, status_code=422)
    return await http_exception_handler(request, exc)


async def _internal_error(request: Request, exc: Exception) -> JSONResponse:
    log.exception("internal error on %s", request.url.path)
    return JSONResponse({"detail": "internal server error"}, status_code=500)


EXCEPTION_HANDLERS: dict[int | type[Exception], Handler] = {
    RequestValidationError: _invalid_request,
    HTTPException: _http_error,
    VispeechError: _answer(400),
    UnknownSession: _answer(404),
    NativeFailure: _answer(422),
    ChatBotError: _answer(502),
    ChatBotTimeout: _answer(504),
    RateLimited: _answer(429),
    Busy: _answer(503),
    Cancelled: _answer(503),
    Exception: _internal_error,
}
"""The application's exception handlers (FastAPI's own answer the other HTTP exceptions: 404, 405, 415)."""
