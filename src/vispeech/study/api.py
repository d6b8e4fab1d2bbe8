"""The participants' routes: the study's texts, joining it, progress, answers and the clips."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import APIRouter, Cookie, Query, Request, Response
from fastapi.responses import FileResponse

from vispeech.guards import client_key
from vispeech.study.dependencies import Running, RunningStudy
from vispeech.study.schemas import AnswerRequest, FaceView, JoinRequest, Progress, QuestionView, StudyView, TrialView
from vispeech.study.store import Participant, StudyError

COOKIE = "vispeech_study"
"""The cookie that holds the participant's stored id."""
NOT_STARTED = "no study started in this browser"

router = APIRouter()


def _clip_url(sentence: str) -> str:
    return f"/clips/{sentence}.mp4"


def _progress(running: RunningStudy, participant: Participant) -> Progress:
    """A participant's trials as the page shows them (clips and columns, never models), and how far they are."""
    views = [
        TrialView(
            task=t.task,
            audio=_clip_url(t.audio),
            faces=[
                FaceView(clip=_clip_url(f.sentence), column=f.column, columns=len(running.clips[f.sentence].models))
                for f in t.faces
            ],
        )
        for t in participant.trials
    ]
    return Progress(trials=views, next=participant.answered, finished=participant.finished)


@router.get("/api/study", response_model=StudyView)
def describe(running: Running) -> StudyView:
    study = running.study
    return StudyView(
        title=study.title,
        intro=study.intro,
        consent=study.consent,
        thanks=study.thanks,
        questions=[QuestionView(**q.model_dump()) for q in study.questions],
        rating_question=study.rating.question if study.rating else None,
        anchors=study.rating.anchors if study.rating else {},
        pairwise_question=study.pairwise.question if study.pairwise else None,
        labels=study.labels,
    )


@router.post("/api/join", response_model=Progress)
def join(
    request: JoinRequest,
    response: Response,
    running: Running,
    connection: Request,
    vispeech_study: str | None = Cookie(default=None),
) -> Progress:
    if not request.consent:
        raise StudyError("the study needs your consent to go on", 400)
    if not running.joins.take(client_key(connection.scope)):
        raise StudyError(f"too many joins from your address: {running.joins.message()}", 429)
    store = running.store
    participant = store.rejoin(vispeech_study) if request.pid is None and vispeech_study else None
    if participant is None:
        participant = store.join(
            f"pid:{request.pid}" if request.pid else f"random:{secrets.token_hex(16)}", request.intro
        )
    response.set_cookie(COOKIE, participant.id, httponly=True, samesite="strict", max_age=90 * 24 * 3600)
    return _progress(running, participant)


@router.get("/api/me", response_model=Progress)
def me(
    running: Running,
    pid: Annotated[str | None, Query(min_length=1, max_length=200)] = None,
    vispeech_study: str | None = Cookie(default=None),
) -> Progress:
    """The progress of the participant this browser's cookie names; with ``pid`` (the page's link
    names one) only if it is that participant's, so that on a shared browser one participant's
    link never continues another's answers."""
    found = running.store.participant(vispeech_study) if vispeech_study else None
    if found is None or (pid is not None and found.id != running.store.participant_id(f"pid:{pid}")):
        raise StudyError(NOT_STARTED, 404)
    return _progress(running, found)


@router.post("/api/answers", response_model=Progress)
def answer(request: AnswerRequest, running: Running, vispeech_study: str | None = Cookie(default=None)) -> Progress:
    if not vispeech_study:
        raise StudyError(NOT_STARTED, 404)
    return _progress(running, running.store.answer(vispeech_study, request.trial, request.answer, request.ms))


@router.get("/clips/{sentence}.mp4")
def clip(sentence: str, running: Running) -> FileResponse:
    if sentence not in running.clips:
        raise StudyError(f"no clip for sentence {sentence!r}", 404)
    return FileResponse(running.clips[sentence].path, media_type="video/mp4")
