"""What the study's page is told and sends: the typed requests and responses of its web API."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from vispeech.study.config import Labels


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
    model_config = ConfigDict(strict=True)  # consent is true, not "yes"

    consent: bool
    pid: str | None = Field(
        default=None,
        min_length=1,
        max_length=200,
        description="A recruitment platform's participant id; one response set per id.",
    )
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
    """A participant's answer, its values as JSON types and nothing converted (``true`` is no
    rating, ``"5"`` no number)."""

    model_config = ConfigDict(strict=True)

    trial: int = Field(ge=0)
    answer: list[int] | Literal["left", "tie", "right"]
    ms: int = Field(ge=0, description="Milliseconds from the trial being shown to the answer.")
