"""The researcher's routes: the answers and participants as CSV, behind the admin token."""

from __future__ import annotations

import hmac

from fastapi import APIRouter, Depends, Request
from fastapi.responses import PlainTextResponse

from vispeech.study.dependencies import Running
from vispeech.study.store import StudyError


def check_admin(request: Request, running: Running, token: str | None = None) -> None:
    """Refuse a request without the admin token (``Authorization: Bearer TOKEN`` or ``?token=``)."""
    given = token or request.headers.get("authorization", "").removeprefix("Bearer ").strip()
    if not given:
        raise StudyError("the export needs the admin token (Authorization: Bearer TOKEN)", 401)
    if not hmac.compare_digest(given.encode(), running.admin_token.encode()):
        raise StudyError("wrong admin token", 403)


router = APIRouter(prefix="/admin", dependencies=[Depends(check_admin)])


def _csv(text: str, name: str) -> PlainTextResponse:
    """``text`` as the CSV file ``name`` to download."""
    return PlainTextResponse(
        text, media_type="text/csv", headers={"Content-Disposition": f'attachment; filename="{name}"'}
    )


@router.get("/answers.csv", response_class=PlainTextResponse)
def answers_csv(running: Running) -> PlainTextResponse:
    return _csv(running.store.export()[0], "answers.csv")


@router.get("/participants.csv", response_class=PlainTextResponse)
def participants_csv(running: Running) -> PlainTextResponse:
    return _csv(running.store.export()[1], "participants.csv")
