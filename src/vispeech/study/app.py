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

from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from vispeech.study import admin, api
from vispeech.study.config import Study
from vispeech.study.dependencies import RunningStudy
from vispeech.study.store import StudyError, StudyStore

STATIC = Path(__file__).with_name("static")


def create_app(study: Study, store: StudyStore, admin_token: str) -> FastAPI:
    """The study's FastAPI app; ``admin_token`` opens the CSV export."""
    app = FastAPI(
        title=f"vispeech study: {study.title}",
        exception_handlers={StudyError: _refused, RequestValidationError: _invalid},
    )
    app.state.study = RunningStudy(study, store, admin_token)
    app.include_router(api.router)
    app.include_router(admin.router)
    app.mount("/", StaticFiles(directory=STATIC, html=True), name="page")
    return app


async def _refused(request: Request, exc: StudyError) -> JSONResponse:
    return JSONResponse({"detail": str(exc)}, status_code=exc.status)


async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
    """A malformed request as one line: the first error's place and message."""
    error = exc.errors()[0] if exc.errors() else {}
    where = ".".join(str(part) for part in error.get("loc", ()) if part not in ("body", "query"))
    return JSONResponse({"detail": f"{where or 'request'}: {error.get('msg', 'invalid')}"}, status_code=422)
