"""A chat reply read as it streams in: its clauses, each to be spoken in the language of its sentence."""

from __future__ import annotations

import base64
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from vispeech.frontends.audio import wav_bytes
from vispeech.frontends.text import Clause, ClauseReader, detect_language, speakable
from vispeech.models.contract import Estimator
from vispeech.motion.rigging.calibration import Calibration
from vispeech.motion.track import Track
from vispeech.text_stream import SpeechTimeline

WHOLE_CLAUSE = 3600.0
"""Seconds of audio in a piece of :func:`speak_reply`'s timeline: more than any clause has."""


class SpokenClause(NamedTuple):
    """A clause of a reply as written (``text``), what of it is spoken (``spoken``), the language
    to speak it in, and whether it is the reply's last."""

    text: str
    spoken: str
    language: str
    last: bool = False


class ReplyReader:
    """The clauses of a reply fed in pieces (:class:`~vispeech.frontends.text.ClauseReader`), each
    with the language of its sentence: the one of ``candidates`` that
    :func:`~vispeech.frontends.text.detect_language` is sure of, told from the sentence so far.

    A clause too short to tell ("Ja,") waits for the next of its sentence and is spoken with it;
    a sentence that ends unsure is spoken in the language of the sentence before (at first,
    ``language``: the page's). Clauses with nothing to say (a link, an emoji) are left out.
    """

    def __init__(self, candidates: Sequence[str], language: str) -> None:
        self.candidates = list(dict.fromkeys([*candidates, language]))
        self.language = language
        self._clauses = ClauseReader()
        self._sentence: str | None = None  # the language of the sentence under way, once told
        self._waiting: list[tuple[str, str]] = []  # clauses (written, spoken) of a sentence not told yet

    def feed(self, text: str) -> list[SpokenClause]:
        """The clauses ``text`` completes, with their languages."""
        return [spoken for clause in self._clauses.feed(text) for spoken in self._place(clause)]

    def finish(self) -> list[SpokenClause]:
        """The clauses left once the reply has ended, the last marked ``last``."""
        out = [spoken for clause in self._clauses.finish() for spoken in self._place(clause)]
        return out[:-1] + [out[-1]._replace(last=True)] if out else []

    def _place(self, clause: Clause) -> list[SpokenClause]:
        spoken = speakable(clause.text)
        if spoken:
            self._waiting.append((clause.text, spoken))
        if self._waiting and self._sentence is None:
            said = detect_language(" ".join(s for _, s in self._waiting), self.candidates)
            if said is None and not clause.ends_sentence:
                return []  # too little to tell: wait for more of the sentence
            self._sentence = said or self.language
        out = []
        if self._waiting:
            assert self._sentence is not None  # told above
            written, said_text = (" ".join(part) for part in zip(*self._waiting))
            out.append(SpokenClause(written, said_text, self._sentence))
            self._waiting = []
        if clause.ends_sentence:
            self.language = self._sentence or self.language
            self._sentence = None
        return out


def speak_reply(
    clauses: Sequence[SpokenClause],
    model: Estimator,
    *,
    fps: float,
    rate: float = 1.0,
    scale: Calibration | None = None,
    voice: str | None = None,
) -> tuple[bytes, Track]:
    """A reply's clauses spoken as the stream speaks them (:class:`~vispeech.text_stream.SpeechTimeline`:
    each in its language, one after another on one timeline): the WAV file of the audio and the
    track (over the stream's channels, in the output scale ``scale``)."""
    timeline = SpeechTimeline(model, fps=fps, rate=rate, chunk_seconds=WHOLE_CLAUSE, scale=scale, voice=voice)
    rows: list[list[float]] = []
    pcm: list[bytes] = []
    for clause in clauses:
        for message in timeline.say(clause.spoken, clause.language, clause.last):
            if message["type"] == "frames":
                rows += message["frames"]
            elif message["type"] == "audio":
                pcm.append(base64.b64decode(message["pcm16"]))
    assert timeline.sample_rate is not None, "a reply has a clause to say"
    samples = np.frombuffer(b"".join(pcm), "<i2")
    track = Track(np.array(rows).reshape(len(rows), len(timeline.channels)), timeline.channels, fps)
    return wav_bytes(samples, timeline.sample_rate), track
