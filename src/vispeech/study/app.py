"""The web app of a perceptual study (``vispeech study serve STUDY.toml``): FastAPI, typed
requests and responses, answers in a :class:`~vispeech.study.store.StudyStore`.

The page (``static/study.html``) walks a participant through the intro, the consent and the
intro questions, then their trials: the clip's faces cropped into canvases labelled A, B, ...
(the page never learns which model is where), answers enabled once the clip has played to its
end, the time to each answer measured on the page. Each answer is committed before the page
shows the next trial; a participant who reloads, or comes back after the server restarted,
goes on where they stopped.

Routes: ``GET /`` the page; ``GET /api/study`` the texts and questions; ``POST /api/join``
(consent and intro answers; sets the participant cookie); ``GET /api/me`` progress;
``POST /api/answers``; ``GET /clips/{sentence}.mp4``; ``GET /admin/answers.csv`` and
``GET /admin/participants.csv`` with ``Authorization: Bearer TOKEN`` (or ``?token=``).
"""

from __future__ import annotations

import hmac
import secrets
from pathlib import Path
from typing import Literal

from fastapi import Cookie, FastAPI, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from vispeech.study.config import Labels, Study
from vispeech.study.store import Participant, StudyError, StudyStore

STATIC = Path(__file__).with_name("static")
COOKIE = "vispeech_study"
"""The cookie that holds the participant's stored id."""
NOT_STARTED = "no study started in this browser"


class QuestionView(BaseModel):
    id: str
    text: str
    choices: list[str]


class StudyView(BaseModel):
    """What the page shows before the trials."""

    title: str
    intro: str
    consent: str
    thanks: str
    questions: list[QuestionView]
    rating_question: str | None
    anchors: dict[int, str]
    pairwise_question: str | None
    labels: Labels


class JoinRequest(BaseModel):
    consent: bool
    pid: str | None = Field(default=None, min_length=1, max_length=200,
                            description="A recruitment platform's participant id; one response set per id.")
    intro: dict[str, str] = Field(default_factory=dict, max_length=50)


class FaceView(BaseModel):
    clip: str
    """URL of the clip the face is cropped from."""
    column: int
    columns: int
    """The face is column ``column`` of ``columns`` equal columns of the clip."""


class TrialView(BaseModel):
    task: Literal["rating", "pairwise"]
    audio: str
    """URL of the clip whose sound plays."""
    faces: list[FaceView]


class Progress(BaseModel):
    trials: list[TrialView]
    next: int
    """The trial to answer next (== len(trials) once finished)."""
    finished: bool


class AnswerRequest(BaseModel):
    trial: int = Field(ge=0)
    answer: list[int] | Literal["left", "tie", "right"]
    ms: int = Field(ge=0, description="Milliseconds from the trial being shown to the answer.")


def create_app(study: Study, store: StudyStore, admin_token: str) -> FastAPI:
    """The study's FastAPI app; ``admin_token`` opens the CSV export."""
    clips = {clip.sentence: clip for clip in study.clips}
    columns = {clip.sentence: len(clip.models) for clip in study.clips}
    app = FastAPI(title=f"vispeech study: {study.title}")

    def url(sentence: str) -> str:
        return f"/clips/{sentence}.mp4"

    def progress(participant: Participant) -> Progress:
        views = [TrialView(task=t.task, audio=url(t.audio),
                           faces=[FaceView(clip=url(f.sentence), column=f.column, columns=columns[f.sentence])
                                  for f in t.faces]) for t in participant.trials]
        return Progress(trials=views, next=participant.answered, finished=participant.finished)

    def known(pid: str | None) -> Participant:
        found = store.participant(pid) if pid else None
        if found is None:
            raise StudyError(NOT_STARTED, 404)
        return found

    @app.exception_handler(StudyError)
    async def refused(request: Request, exc: StudyError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=exc.status)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        error = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(part) for part in error.get("loc", ()) if part not in ("body", "query"))
        return JSONResponse({"detail": f"{where or 'request'}: {error.get('msg', 'invalid')}"}, status_code=422)

    @app.get("/api/study", response_model=StudyView)
    def describe() -> StudyView:
        return StudyView(title=study.title, intro=study.intro, consent=study.consent, thanks=study.thanks,
                         questions=[QuestionView(**q.model_dump()) for q in study.questions],
                         rating_question=study.rating.question if study.rating else None,
                         anchors=study.rating.anchors if study.rating else {},
                         pairwise_question=study.pairwise.question if study.pairwise else None,
                         labels=study.labels)

    @app.post("/api/join", response_model=Progress)
    def join(request: JoinRequest, response: Response, vispeech_study: str | None = Cookie(default=None)) -> Progress:
        if not request.consent:
            raise StudyError("the study needs your consent to go on", 400)
        participant = store.rejoin(vispeech_study) if request.pid is None and vispeech_study else None
        if participant is None:
            participant = store.join(f"pid:{request.pid}" if request.pid else f"random:{secrets.token_hex(16)}",
                                     request.intro)
        response.set_cookie(COOKIE, participant.id, httponly=True, samesite="strict", max_age=90 * 24 * 3600)
        return progress(participant)

    @app.get("/api/me", response_model=Progress)
    def me(vispeech_study: str | None = Cookie(default=None)) -> Progress:
        return progress(known(vispeech_study))

    @app.post("/api/answers", response_model=Progress)
    def answer(request: AnswerRequest, vispeech_study: str | None = Cookie(default=None)) -> Progress:
        if not vispeech_study:
            raise StudyError(NOT_STARTED, 404)
        return progress(store.answer(vispeech_study, request.trial, request.answer, request.ms))

    @app.get("/clips/{sentence}.mp4")
    def clip(sentence: str) -> FileResponse:
        if sentence not in clips:
            raise StudyError(f"no clip for sentence {sentence!r}", 404)
        return FileResponse(clips[sentence].path, media_type="video/mp4")

    def admin(request: Request, token: str | None) -> None:
        given = token or request.headers.get("authorization", "").removeprefix("Bearer ").strip()
        if not given:
            raise StudyError("the export needs the admin token (Authorization: Bearer TOKEN)", 401)
        if not hmac.compare_digest(given.encode(), admin_token.encode()):
            raise StudyError("wrong admin token", 403)

    @app.get("/admin/answers.csv", response_class=PlainTextResponse)
    def answers_csv(request: Request, token: str | None = None) -> PlainTextResponse:
        admin(request, token)
        return PlainTextResponse(store.export()[0], media_type="text/csv",
                                 headers={"Content-Disposition": 'attachment; filename="answers.csv"'})

    @app.get("/admin/participants.csv", response_class=PlainTextResponse)
    def participants_csv(request: Request, token: str | None = None) -> PlainTextResponse:
        admin(request, token)
        return PlainTextResponse(store.export()[1], media_type="text/csv",
                                 headers={"Content-Disposition": 'attachment; filename="participants.csv"'})

    app.mount("/", StaticFiles(directory=STATIC, html=True), name="page")
    return app
