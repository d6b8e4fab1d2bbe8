"""What FastAPI's ``Depends`` gives the routes: the application's speech service, the client's address."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends
from starlette.requests import HTTPConnection

from vispeech.guards import client_key
from vispeech.serve.service import SpeechService


async def speech_service(connection: HTTPConnection) -> SpeechService:
    """The :class:`SpeechService` of the application that ``connection`` came to."""
    return connection.app.state.service


Service = Annotated[SpeechService, Depends(speech_service)]
"""A route parameter given the application's speech service."""


async def client_ip(connection: HTTPConnection) -> str:
    """The client's IP address (what the rate limit and the work pool count by)."""
    return client_key(connection.scope)


ClientIP = Annotated[str, Depends(client_ip)]
"""A route parameter given the client's IP address."""
