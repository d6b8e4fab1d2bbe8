"""The web app of a perceptual study (``vispeech study serve STUDY.toml``): FastAPI, typed
requests and responses, answers in a :class:`~vispeech.study.store.StudyStore`.

The page (``static/study.html``) walks a participant through the intro, the consent and the
intro questions, then their trials: the clip's faces cropped into canvases labelled A, B, ...
(the page never learns which model is where), answers enabled once the clip has played to its
end, the time to each answer measured on the page. Each answer is committed before the page
shows the next trial; a participant who reloads, or comes back after the server restarted,
goes on where they stopped.

Routes:

- :mod:`~vispeech.study.api`: ``GET /api/study`` the texts and questions; ``POST /api/join``
  (consent and intro answers; sets the participant cookie); ``GET /api/me`` progress;
  ``POST /api/answers``; ``GET /clips/{sentence}.mp4``;
- :mod:`~vispeech.study.admin`: ``GET /admin/answers.csv`` and ``GET /admin/participants.csv``
  with ``Authorization: Bearer TOKEN`` (or ``?token=``);
- ``GET /`` the page (``static/``).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from vispeech.guards import (
    DEFAULT_ALLOWED_HOSTS,
    BodySizeLimit,
    HostOriginCheck,
    TokenBucket,
    keep_tokens_out_of_logs,
)
from vispeech.study import admin, api
from vispeech.study.config import Study
from vispeech.study.dependencies import RunningStudy
from vispeech.study.store import StudyError, StudyStore

STATIC = Path(__file__).with_name("static")
MAX_BODY_BYTES = 64 * 1024
"""The largest request body (bytes): a join's intro answers or an answer need far less."""
JOIN_RATE = 0.2
"""Joins a second a client address may make (one every 5 s) once its burst is spent."""
JOIN_BURST = 10
"""Joins a client address may make at once."""


def create_app(
    study: Study,
    store: StudyStore,
    admin_token: str,
    allowed_hosts: Iterable[str] = DEFAULT_ALLOWED_HOSTS,
    allowed_origins: Iterable[str] | None = None,
    max_body_bytes: int = MAX_BODY_BYTES,
    joins: TokenBucket | None = None,
) -> FastAPI:
    """The study's FastAPI app; ``admin_token`` opens the CSV export.

    The guards of ``vispeech serve`` (:mod:`vispeech.guards`): a ``Host`` outside
    ``allowed_hosts`` gets 400 and a POST from a foreign ``Origin`` 403
    (:class:`~vispeech.guards.HostOriginCheck`), a body over ``max_bytes`` 413 before it is
    parsed, and joins past ``joins`` (per client address; default :data:`JOIN_RATE` a second in
    bursts of :data:`JOIN_BURST`) 429. ``token=`` query values are kept out of uvicorn's logs.
    """
    keep_tokens_out_of_logs()
    app = FastAPI(
        title=f"vispeech study: {study.title}",
        exception_handlers={StudyError: _refused, RequestValidationError: _invalid},
    )
    app.state.study = RunningStudy(study, store, admin_token, joins or TokenBucket(JOIN_RATE, JOIN_BURST))
    app.add_middleware(BodySizeLimit, max_bytes=max_body_bytes)
    app.add_middleware(HostOriginCheck, allowed_hosts=allowed_hosts, allowed_origins=allowed_origins)
    app.include_router(api.router)
    app.include_router(admin.router)
    app.mount("/", StaticFiles(directory=STATIC, html=True), name="page")
    return app


async def _refused(request: Request, exc: StudyError) -> JSONResponse:
    return JSONResponse({"detail": str(exc)}, status_code=exc.status)


async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
    """A malformed request as one line: the first error's place and message."""
    error = exc.errors()[0] if exc.errors() else {}
    loc = [str(part) for part in error.get("loc", ()) if part not in ("body", "query")]
    if loc[:1] == ["answer"] and len(loc) == 2:  # neither of the two kinds of answer: say both
        return JSONResponse({"detail": ANSWER_KINDS}, status_code=422)
    where = ".".join(loc)
    return JSONResponse({"detail": f"{where or 'request'}: {error.get('msg', 'invalid')}"}, status_code=422)


ANSWER_KINDS = "answer: a rating trial's is a list of whole numbers, a pairwise trial's 'left', 'tie' or 'right'"
"""What a malformed answer is told (pydantic would name only the first kind it tried)."""
