"""What FastAPI's ``Depends`` gives the study's routes: the study being run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends
from starlette.requests import HTTPConnection

from vispeech.guards import TokenBucket
from vispeech.study.config import Clip, Study
from vispeech.study.store import StudyStore


@dataclass
class RunningStudy:
    """A study being served: its plan, the store of its answers, the token that opens the export,
    the rate limit of joins (per client address), and its clips by sentence."""

    study: Study
    store: StudyStore
    admin_token: str
    joins: TokenBucket
    clips: dict[str, Clip] = field(init=False)

    def __post_init__(self) -> None:
        self.clips = {clip.sentence: clip for clip in self.study.clips}


async def running_study(connection: HTTPConnection) -> RunningStudy:
    """The :class:`RunningStudy` of the application that ``connection`` came to."""
    return connection.app.state.study


Running = Annotated[RunningStudy, Depends(running_study)]
"""A route parameter given the study being run."""
