"""Text spoken clause by clause, as ``/api/stream`` messages.

:func:`speech_messages` splits the text into sentences and clauses
(:func:`~vispeech.frontends.text.split_clauses`: after ``. ! ? ; : , …`` followed by white
space, and at line breaks), synthesises and animates each in turn (a :class:`SpeechTimeline`,
which also speaks clauses as they come, each in its own language) and gives the ``/api/stream``
protocol messages for it at once, so the first frames and audio leave after the first clause,
not after the whole text. The first clause starts with the silence
:func:`~vispeech.pipeline.speak` puts before speech, the last ends with the silence it adds
after, so that the mouth opens from rest and comes back to it. The clauses follow each other on
one timeline: frame k sits at ``k / fps`` seconds from the start of the first clause's audio,
and a frame that falls between two clauses' frame grids is interpolated from its own clause's
track. Audio goes in pieces of ``chunk_seconds`` (PCM16, base64), each preceded by the frames up
to its end.

The heavy part of a clause, speaking it and animating it (:func:`voice_clauses`), needs nothing
of the timeline but what :meth:`SpeechTimeline.clause` hands it, so a server voices the
clauses of many streams together, in other processes, and puts each on its timeline after
(:meth:`SpeechTimeline.place`).
"""

from __future__ import annotations

import base64
from collections.abc import Generator, Iterable, Sequence
from dataclasses import replace
from typing import NamedTuple, cast

import numpy as np

from vispeech.alignment.phones import PhoneSequence, n_frames_for
from vispeech.errors import VispeechError
from vispeech.frontends.audio import to_pcm16
from vispeech.frontends.sentiment import sentiment
from vispeech.frontends.text import split_clauses
from vispeech.models.contract import Estimator
from vispeech.motion.life import LifePlan
from vispeech.motion.rigging.calibration import Calibration
from vispeech.motion.track import Track, interpolate_rows
from vispeech.pipeline import DEFAULT_FPS, LEADING_SILENCE, TRAILING_SILENCE, animate_many, padded, spoken_text
from vispeech.streaming import stream_channels


def speech_messages(
    text: str,
    language: str,
    model: Estimator,
    *,
    fps: float = DEFAULT_FPS,
    rate: float = 1.0,
    chunk_seconds: float = 0.1,
    scale: Calibration | None = None,
    voice: str | None = None,
    life: Iterable[str] = (),
    seed: int = 0,
) -> Generator[list[dict], None, None]:
    """The ``/api/stream`` messages for ``text``, one list per clause, computed as they are asked for.

    The first list begins with ``start`` (``fps``, ``channels``, ``sample_rate``, ``model``);
    then come ``frames`` (``start_frame``, ``frames``) and ``audio`` (``seq``, ``start`` in
    seconds, ``pcm16`` base64 little-endian mono) in time order; the last list is ``[end]``
    (``n_frames``, ``duration`` in seconds). The frames cover the audio as
    :func:`vispeech.pipeline.speak` would: ``ceil(duration · fps)`` of them, in the output
    ``scale`` (``None``: the model's own), spoken with the espeak-ng ``voice``, with the
    non-verbal layers ``life`` drawn with ``seed`` (:class:`~vispeech.motion.life.LifePlan`).
    """
    clauses = split_clauses(spoken_text(text))
    timeline = SpeechTimeline(
        model, fps=fps, rate=rate, chunk_seconds=chunk_seconds, scale=scale, voice=voice, life=life, seed=seed
    )
    for k, clause in enumerate(clauses):
        yield timeline.say(clause, language, last=k == len(clauses) - 1)
    yield timeline.end()


class Clause(NamedTuple):
    """A clause to voice (:func:`voice_clauses`), as :meth:`SpeechTimeline.clause` asks for it:
    its spoken ``text`` and ``language``, the frame rate, the speaking rate, the espeak-ng
    ``voice``, the seconds of silence put ``lead``-ing before it and ``trail``-ing after it, and
    the ``channels`` its frames carry."""

    text: str
    language: str
    fps: float
    rate: float
    voice: str | None
    lead: float
    trail: float
    channels: tuple[str, ...]


class VoicedClause(NamedTuple):
    """A clause spoken and animated: its ``text``, audio (``pcm``, 16-bit, at ``sample_rate``)
    and ``phones``, with the silences asked for, and its frames (``values``: rows over
    ``channels`` at the clause's frame rate from its start, post-processed as
    :func:`~vispeech.pipeline.animate` does)."""

    text: str
    pcm: np.ndarray
    sample_rate: int
    phones: PhoneSequence
    values: np.ndarray
    channels: tuple[str, ...]


def voice_clauses(model: Estimator, clauses: Sequence[Clause]) -> list[VoicedClause | VispeechError]:
    """Each clause spoken by espeak-ng (reusing its library: latency first) and animated by
    ``model``, the clauses of one frame rate in one call of the model
    (:func:`~vispeech.pipeline.animate_many`); in the place of a clause that cannot be said, its
    :class:`VispeechError`."""
    from vispeech.frontends.espeak import synthesize

    out: dict[int, VoicedClause | VispeechError] = {}
    spoken = {}
    for k, clause in enumerate(clauses):
        try:
            speech = synthesize(clause.text, clause.language, clause.rate, voice=clause.voice, reproducible=False)
        except VispeechError as exc:
            out[k] = exc
        else:
            spoken[k] = padded(speech, clause.lead, clause.trail)
    groups: dict[float, list[int]] = {}
    for k in spoken:
        groups.setdefault(clauses[k].fps, []).append(k)
    for fps, members in groups.items():
        for k, track in zip(members, animate_many([spoken[k].phones for k in members], model, fps)):
            clause, speech = clauses[k], spoken[k]
            out[k] = (
                track
                if isinstance(track, VispeechError)
                else VoicedClause(
                    clause.text,
                    to_pcm16(speech.audio),
                    speech.sample_rate,
                    speech.phones,
                    track.select(clause.channels).values,
                    clause.channels,
                )
            )
    return [out[k] for k in range(len(clauses))]


class SpeechTimeline:
    """Clauses spoken one after another on one timeline, each in its own language (a chat
    reply's sentences in theirs): the ``/api/stream`` messages of each, as :func:`speech_messages`
    gives them, computed when it is said.

    The channels are those of the first clause's phone set, then those of the ``life`` layers; the
    espeak-ng ``voice`` (a variant: ``f3``) speaks every language.
    """

    def __init__(
        self,
        model: Estimator,
        *,
        fps: float = DEFAULT_FPS,
        rate: float = 1.0,
        chunk_seconds: float = 0.1,
        scale: Calibration | None = None,
        voice: str | None = None,
        life: Iterable[str] = (),
        seed: int = 0,
    ) -> None:
        self.model, self.fps, self.rate, self.scale, self.voice = model, fps, rate, scale, voice
        self.chunk_seconds = chunk_seconds
        self.life = LifePlan(life, fps, seed, scale) if life else None  # the non-verbal layers, if any
        self.said = ""  # every clause so far: the expression's mood
        self.channels: tuple[str, ...] = ()
        self.speech_channels: tuple[str, ...] = ()  # the model's, before the life layers' channels
        self.sample_rate: int | None = None
        self.samples = self.frames = self.seq = 0

    @property
    def duration(self) -> float:
        """Seconds of audio said so far."""
        return self.samples / self.sample_rate if self.sample_rate else 0.0

    def say(self, clause: str, language: str, last: bool = False) -> list[dict]:
        """The messages of ``clause`` (spoken text) in ``language``: ``start`` first when it is the first
        clause, which begins with the silence :func:`~vispeech.pipeline.speak` puts before speech; a
        ``last`` clause ends with the silence it adds after. :meth:`clause` and :meth:`place` in one."""
        request = self.clause(clause, language, last)
        voiced = voice_clauses(self.model, [request])[0]
        if isinstance(voiced, VispeechError):
            raise voiced
        return self.place(voiced)

    def clause(self, clause: str, language: str, last: bool = False) -> Clause:
        """What :meth:`say` hands to :func:`voice_clauses` for ``clause``: the timeline's next clause."""
        from vispeech.frontends.espeak import phone_set

        first = self.sample_rate is None
        channels = stream_channels(self.model, phone_set(language), self.fps) if first else self.speech_channels
        lead, trail = LEADING_SILENCE if first else 0.0, TRAILING_SILENCE if last else 0.0
        return Clause(clause, language, self.fps, self.rate, self.voice, lead, trail, channels)

    def place(self, voiced: VoicedClause) -> list[dict]:
        """The messages of a clause :meth:`clause` asked for, voiced, put on the timeline after
        those before it."""
        messages: list[dict] = []
        if self.sample_rate is None:
            self.speech_channels = voiced.channels
            self.sample_rate = voiced.sample_rate
            self.channels = self.life.joined_channels(voiced.channels) if self.life else voiced.channels
            start = {"fps": self.fps, "channels": list(self.channels), "sample_rate": self.sample_rate}
            messages.append({"type": "start", **start, "model": self.model.name})
        elif voiced.sample_rate != self.sample_rate:
            raise VispeechError(
                f"{voiced.phones.language} speaks at {voiced.sample_rate} Hz, this stream at {self.sample_rate} Hz"
            )
        values = voiced.values
        if self.scale is not None:
            values = self.scale.apply(Track(values, voiced.channels, self.fps)).values
        self.said += f" {voiced.text}"
        return messages + self._pieces(voiced.pcm, values, voiced.phones)

    def _pieces(self, pcm: np.ndarray, values: np.ndarray, phones: PhoneSequence) -> list[dict]:
        """``frames`` and ``audio`` messages of a clause's audio, track (rows at ``fps`` from its
        start) and phones, in pieces of ``chunk_seconds``, each piece's frames before its audio."""
        rate, fps = cast(int, self.sample_rate), self.fps
        clause_start = self.samples / rate
        frame_end = _frames_before((self.samples + len(pcm)) / rate, fps)
        values = interpolate_rows(values, np.arange(self.frames, frame_end) - clause_start * fps)
        if self.life is not None:
            mood = sentiment(self.said, phones.language) if "expression" in self.life.layers else 0.0
            timed = [replace(p, start=p.start + clause_start, end=p.end + clause_start) for p in phones]
            track = Track(values, self.speech_channels, fps, self.frames / fps)
            values = self.life.join(track, timed, phones.language, mood).values
        step = max(1, round(self.chunk_seconds * rate))
        messages: list[dict] = []
        sent = self.frames
        for a in range(0, len(pcm), step):
            b = min(a + step, len(pcm))
            upto = frame_end if b == len(pcm) else min(frame_end, _frames_before((self.samples + b) / rate, fps))
            if upto > sent:
                rows = np.round(values[sent - self.frames : upto - self.frames], 6).tolist()
                messages.append({"type": "frames", "start_frame": sent, "frames": rows})
                sent = upto
            pcm16 = base64.b64encode(pcm[a:b].tobytes()).decode("ascii")
            messages.append({"type": "audio", "seq": self.seq, "start": (self.samples + a) / rate, "pcm16": pcm16})
            self.seq += 1
        self.samples += len(pcm)
        self.frames = frame_end
        return messages

    def end(self) -> list[dict]:
        """The ``end`` message (``n_frames``, ``duration``)."""
        if self.sample_rate is None:
            raise VispeechError("nothing was said")
        return [{"type": "end", "n_frames": self.frames, "duration": self.duration}]


def _frames_before(seconds: float, fps: float) -> int:
    """Frames whose time ``k / fps`` lies before ``seconds`` (none at 0)."""
    return n_frames_for(seconds, fps) if seconds > 0 else 0
