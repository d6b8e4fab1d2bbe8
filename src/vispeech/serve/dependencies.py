"""What FastAPI's ``Depends`` gives the routes: the application's speech service."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends
from starlette.requests import HTTPConnection

from vispeech.serve.service import SpeechService


def speech_service(connection: HTTPConnection) -> SpeechService:
    """The :class:`SpeechService` of the application that ``connection`` came to."""
    return connection.app.state.service


Service = Annotated[SpeechService, Depends(speech_service)]
"""A route parameter given the application's speech service."""
