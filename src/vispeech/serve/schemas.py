"""Request and response bodies of the HTTP API and the messages of the ``/api/stream`` and
``/api/listen`` WebSockets.

The field names are the browser contract of ``docs/web.md``; the bounds here are the
server's input limits (text length, phones per message, stream length, frame and sample rates).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StringConstraints, TypeAdapter, model_validator

from vispeech.errors import VispeechError
from vispeech.frontends.audio import MAX_SAMPLE_RATE, MIN_SAMPLE_RATE
from vispeech.frontends.espeak import MAX_RATE, MIN_RATE, check_voice
from vispeech.limits import MAX_FPS, MIN_FPS
from vispeech.motion.formats.animation_json import ANIMATION_FORMAT

MAX_TEXT_CHARS = 1000
"""Longest text (characters) that ``/api/speak``, ``/api/chat`` and the stream accept."""

MAX_PHONES_PER_MESSAGE = 500
"""Most phones one ``phones`` stream message may carry."""

MAX_STREAM_SECONDS = 600.0
"""Latest phone end (seconds) a phone stream may reach."""

MAX_TIMINGS = 1000
"""Most characters, words or visemes one ``/api/listen`` timings message may carry."""

_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def _printable(text: str) -> str:
    if _CONTROL.search(text):
        raise ValueError("text must not contain control characters")
    return text


def _taken(check: Callable[[str], object], value: str) -> str:
    """``value`` when ``check`` takes it; the :class:`VispeechError` it raises as the ``ValueError``
    pydantic reports (a 422 naming the field)."""
    try:
        check(value)
    except VispeechError as exc:
        raise ValueError(str(exc)) from None
    return value


def _known_voice(voice: str) -> str:
    return _taken(check_voice, voice)


def _spoken_language(code: str) -> str:
    from vispeech.frontends.espeak import find_language

    return find_language(code).code


Language = Annotated[
    str, StringConstraints(strip_whitespace=True, min_length=1, max_length=40), AfterValidator(_spoken_language)
]
"""A language espeak-ng speaks (``vispeech languages``), read as its own code (``fr`` -> ``fr-fr``)."""
PhoneSet = Literal["sv", "en", "ipa"]
"""The phone set of timed phones: Swedish, English (ARPAbet) or IPA."""
Text = Annotated[
    str, StringConstraints(strip_whitespace=True, min_length=1, max_length=MAX_TEXT_CHARS), AfterValidator(_printable)
]
Voice = Annotated[
    str, StringConstraints(strip_whitespace=True, min_length=1, max_length=40), AfterValidator(_known_voice)
]
"""An espeak-ng voice (``vispeech languages --voices``): f1-f5 female, m1-m8 male, ..."""
Scale = Literal["arkit", "tracker"]
"""A named output scale (:func:`vispeech.motion.rigging.calibration.load_scale`): ``arkit`` (the
shipped calibration) or ``tracker`` (the models' own)."""
Rate = Annotated[float, Field(ge=MIN_RATE, le=MAX_RATE, allow_inf_nan=False)]
Seconds = Annotated[float, Field(ge=0.0, le=MAX_STREAM_SECONDS, allow_inf_nan=False)]
ModelName = Annotated[str, StringConstraints(min_length=1, max_length=100)]
Fps = Annotated[float, Field(ge=MIN_FPS, le=MAX_FPS, allow_inf_nan=False)]
SampleRate = Annotated[int, Field(ge=MIN_SAMPLE_RATE, le=MAX_SAMPLE_RATE)]
Layer = Literal["blink", "gaze", "head", "brows", "breath", "expression"]
"""A non-verbal layer (:data:`vispeech.motion.life.LAYERS`)."""
Layers = Annotated[list[Layer], Field(max_length=10)]
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]
FileFormat = Literal["livelink", "talkinghead", "oculus", "rhubarb"]
"""A track format an answer can carry as a file (:data:`vispeech.motion.formats.registry.TEXT_FORMATS`)."""
Formats = Annotated[list[FileFormat], Field(max_length=4)]
SessionId = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_-]{1,64}$")]
"""A chat session's id, as the server drew it."""


class ClientInput(BaseModel):
    """A JSON body or message a client sends: a field the server does not know is refused (422
    naming it), never ignored. (Query strings may carry more: the access ``token``.)"""

    model_config = ConfigDict(extra="forbid")


class Speaking(ClientInput):
    """How a text is spoken and animated, in a request or a stream message; ``null`` means the
    server's setting (its default model, voice, frame rate and output scale). ``voice`` is an
    espeak-ng voice, ``scale`` an output scale."""

    language: Language = "en"
    model: ModelName | None = None
    voice: Voice | None = None
    rate: Rate = 1.0
    fps: Fps | None = None
    scale: Scale | None = None


class LifeOptions(ClientInput):
    """``life`` names the non-verbal layers to add to the animation (:mod:`vispeech.motion.life`),
    drawn with ``seed``."""

    life: Layers = []
    seed: Seed = 0


class AnswerOptions(LifeOptions):
    """What an answer (:class:`SpeakResponse`) carries besides the speech: the layers of
    :class:`LifeOptions`; ``formats`` the track formats the answer carries as files
    (:attr:`SpeakResponse.files`)."""

    formats: Formats = []


class SpeechOptions(AnswerOptions, Speaking):
    """The options of :class:`Speaking` and of :class:`AnswerOptions`."""


class SpeakRequest(SpeechOptions):
    """Text to speak, with the options of :class:`SpeechOptions`."""

    text: Text


class AnimateQuery(AnswerOptions):
    """Query parameters of ``POST /api/animate`` (the body is the audio file itself).

    ``model`` (default: the server's upload model, else what ``vispeech animate`` takes:
    :func:`vispeech.pipeline.recording_model`) animates the audio; with ``text`` the transcript
    is aligned with the audio in ``language`` and its phones drive or join the model, as
    :func:`vispeech.pipeline.listen` does; an English transcript that does not fit the
    audio is refused (400) unless ``force``. ``fps`` and ``scale`` ``null`` mean the server's
    frame rate and output scale; ``life``, ``seed`` and ``formats`` as in :class:`AnswerOptions`
    (a list repeated: ``formats=oculus&formats=rhubarb``). A parameter it does not take is a 422.
    """

    text: Text | None = None
    language: Language = "en"
    fps: Fps | None = None
    scale: Scale | None = None
    model: ModelName | None = None
    force: bool = False
    formats: Formats = []


class WordJSON(BaseModel):
    text: str
    start: float
    end: float


class PhoneJSON(BaseModel):
    symbol: str
    start: float
    end: float
    word: int | None = None
    stress: int = 0


class PhonesJSON(BaseModel):
    """A :class:`vispeech.PhoneSequence` as :meth:`~vispeech.PhoneSequence.to_dict` writes it."""

    language: str
    words: list[WordJSON]
    phones: list[PhoneJSON]


class AnimationJSON(BaseModel):
    """vispeech animation JSON (see :mod:`vispeech.motion.formats.animation_json`): frame k at ``k / fps`` s."""

    format: Literal["vispeech-animation"] = ANIMATION_FORMAT
    version: int = 1
    fps: float
    start_time: float = 0.0
    n_frames: int
    channels: list[str]
    frames: list[list[float]]
    phones: PhonesJSON | None = None


class SpeakResponse(BaseModel):
    """Audio URL and animation of one utterance; ``cached`` tells whether it came from the cache."""

    audio_url: str
    animation: AnimationJSON
    text: str
    cached: bool
    files: dict[FileFormat, str] = {}
    """Each format the request asked for → the text of the animation's file in it (Live Link Face
    CSV, TalkingHead JSON, Oculus viseme CSV, Rhubarb cue TSV), as ``vispeech say`` writes it."""


class ChatRequest(SpeechOptions):
    """A chat message in ``session`` (``null``: a new one); with ``speak`` the reply comes spoken
    (``speech``) with the options of :class:`SpeechOptions` (``language``: the page's; each
    sentence of the reply is spoken in its own)."""

    message: Text
    session: SessionId | None = None
    speak: bool = True


class ChatResponse(BaseModel):
    """The reply (its clauses as written, code blocks left out), the language most of it is in, the
    session to send the next message in. A reply in one language is spoken whole; one in several
    is spoken as the stream speaks it, each sentence in its language, clause by clause, and its
    ``speech`` has the stream's channels and no phones."""

    reply: str
    language: str
    session: str
    speech: SpeakResponse | None = None


class ConfigResponse(BaseModel):
    """What the web app needs to know about the server."""

    avatar_url: str | None
    avatar_credit: str | None = None
    languages: list[str]
    """Codes of the languages text is spoken in: sv and en first, then every other espeak-ng voice."""
    language_names: dict[str, str] = {}
    """Each language's name, as espeak-ng gives it (``de``: ``German``)."""
    chat_languages: list[str] | None = None
    """The languages the chat bot answers in (``null``: any)."""
    models: list[str]
    """Models that animate text and phones (``/api/speak``, ``/api/chat``, ``/api/stream``)."""
    audio_models: list[str] = []
    """Models that animate audio alone (``/api/animate`` and ``/api/listen`` without a transcript)."""
    default_model: str
    stream_model: str
    audio_model: str | None = None
    fps: float
    max_text: int
    token_required: bool = False


class ErrorResponse(BaseModel):
    detail: str


class TextMessage(Speaking, LifeOptions):
    """Stream client message: speak ``text`` clause by clause, as :class:`Speaking` says, with the
    non-verbal layers of :class:`LifeOptions` (their channels after the speech's)."""

    type: Literal["text"]
    text: Text


class ChatStreamMessage(Speaking, LifeOptions):
    """Stream client message: a chat message in ``session`` (``null``: a new one); the reply is
    spoken clause by clause as the bot writes it, each sentence in its own language, with the
    model, voice, rate, frame rate and output scale of :class:`Speaking` (``language``: the page's)
    and the non-verbal layers of :class:`LifeOptions`."""

    type: Literal["chat"]
    message: Text
    session: SessionId | None = None


class StreamPhone(ClientInput):
    """One timed phone of a phone stream, seconds from the stream's start."""

    symbol: Annotated[str, StringConstraints(min_length=1, max_length=8)]
    start: Seconds
    end: Seconds
    stress: Annotated[int, Field(ge=0, le=2)] = 0


class PhonesMessage(ClientInput):
    """Stream client message: the next phones of a phone stream; ``final`` ends it.

    ``language`` (default ``"en"``), ``model`` (the stream model), ``fps`` (the server's frame
    rate) and ``scale`` (the server's output scale) are set by a stream's first message; a later
    one may repeat them, not change them.
    """

    type: Literal["phones"]
    phones: Annotated[list[StreamPhone], Field(max_length=MAX_PHONES_PER_MESSAGE)]
    language: PhoneSet | None = None
    final: bool = False
    model: ModelName | None = None
    fps: Fps | None = None
    scale: Scale | None = None


ClientMessage = TypeAdapter(Annotated[TextMessage | ChatStreamMessage | PhonesMessage, Field(discriminator="type")])
"""Parses one stream client message (JSON text) into :class:`TextMessage`, :class:`ChatStreamMessage`
or :class:`PhonesMessage`."""


class AudioStartMessage(ClientInput):
    """Listen client message: open an audio stream; binary messages of audio follow, each a chunk
    of ``encoding`` (``pcm16``: 16-bit little-endian mono PCM) at ``sample_rate`` Hz.

    ``timings`` ``null``: the audio model animates the audio (``model`` ``null``: the server's
    audio model). ``characters``, ``words`` or ``visemes``: the client sends the voice service's
    timings of that kind as they come (:class:`CharactersMessage`, :class:`WordsMessage`,
    :class:`VisemesMessage`), and a phone model animates them (``model`` ``null``: the stream
    model), words and characters read in ``language``. ``fps`` and ``scale`` ``null`` mean the
    server's frame rate and output scale.
    """

    type: Literal["start"]
    sample_rate: SampleRate
    encoding: Literal["pcm16"] = "pcm16"
    fps: Fps | None = None
    scale: Scale | None = None
    model: ModelName | None = None
    timings: Literal["characters", "words", "visemes"] | None = None
    language: Language = "en"


class AudioStopMessage(ClientInput):
    """Listen client message: the audio has ended; the server sends the last frames and ``end``."""

    type: Literal["stop"]


class CancelMessage(ClientInput):
    """Listen client message: the listener interrupted (barge-in). The audio and timings waiting
    are dropped and the latest stream (the open one, else the one that ended last) ends at once
    with a ``cancelled`` message easing the face to rest from ``frame``, the frame the client
    shows (``null``: the last frame sent)."""

    type: Literal["cancel"]
    frame: Annotated[int, Field(ge=0)] | None = None


def _timed_in_order(starts: list[float], ends: list[float], what: str) -> None:
    for k, (start, end) in enumerate(zip(starts, ends)):
        if end < start:
            raise ValueError(f"{what} {k} ends ({end}) before it starts ({start})")
        if k and start < starts[k - 1]:
            raise ValueError(f"{what} {k} starts ({start}) before the one before it ({starts[k - 1]})")


class CharactersMessage(ClientInput):
    """Listen client message: the next characters of a ``characters`` stream with their times,
    seconds from the start of the stream's audio, as ElevenLabs' ``alignment`` gives them."""

    type: Literal["characters"]
    characters: Annotated[
        list[Annotated[str, StringConstraints(min_length=1, max_length=8)]], Field(max_length=MAX_TIMINGS)
    ]
    character_start_times_seconds: Annotated[list[Seconds], Field(max_length=MAX_TIMINGS)]
    character_end_times_seconds: Annotated[list[Seconds], Field(max_length=MAX_TIMINGS)]

    @model_validator(mode="after")
    def _timed(self) -> CharactersMessage:
        starts, ends = self.character_start_times_seconds, self.character_end_times_seconds
        if not len(self.characters) == len(starts) == len(ends):
            raise ValueError(
                f"characters and their times must be as many: {len(self.characters)} characters, "
                f"{len(starts)} start times, {len(ends)} end times"
            )
        _timed_in_order(starts, ends, "character")
        return self


class TimedWord(ClientInput):
    """One word with its start and end, seconds from the start of the stream's audio."""

    text: Annotated[str, StringConstraints(min_length=1, max_length=100), AfterValidator(_printable)]
    start: Seconds
    end: Seconds


class WordsMessage(ClientInput):
    """Listen client message: the next words of a ``words`` stream with their times (Azure's word
    boundaries, a transcript's word times)."""

    type: Literal["words"]
    words: Annotated[list[TimedWord], Field(max_length=MAX_TIMINGS)]

    @model_validator(mode="after")
    def _timed(self) -> WordsMessage:
        _timed_in_order([w.start for w in self.words], [w.end for w in self.words], "word")
        return self


def _known_viseme(name: str) -> str:
    from vispeech.frontends.timings import viseme_phone

    return _taken(viseme_phone, name)


class TimedViseme(ClientInput):
    """One viseme from ``time`` (seconds from the start of the stream's audio) to the next one's:
    an Azure viseme id (0–21) or an Oculus viseme name (``sil``, ``PP``, ``FF``, ... ``ou``)."""

    viseme: Annotated[int, Field(strict=True, ge=0, le=21)] | Annotated[str, AfterValidator(_known_viseme)]
    time: Seconds


class VisemesMessage(ClientInput):
    """Listen client message: the next visemes of a ``visemes`` stream, in time order."""

    type: Literal["visemes"]
    visemes: Annotated[list[TimedViseme], Field(max_length=MAX_TIMINGS)]

    @model_validator(mode="after")
    def _timed(self) -> VisemesMessage:
        times = [v.time for v in self.visemes]
        _timed_in_order(times, times, "viseme")
        return self


LISTEN_MESSAGE_TYPES = ("start", "stop", "cancel", "characters", "words", "visemes")
"""The ``type`` of every ``/api/listen`` client text message."""

ListenClientMessage = TypeAdapter(
    Annotated[
        AudioStartMessage | AudioStopMessage | CancelMessage | CharactersMessage | WordsMessage | VisemesMessage,
        Field(discriminator="type"),
    ]
)
"""Parses one ``/api/listen`` client text message into its model (:data:`LISTEN_MESSAGE_TYPES`)."""


class StartMessage(BaseModel):
    """Stream server message, first of a stream: the frame rate and channels of the frames to come.

    ``sample_rate`` is the audio's (``None`` for a phone stream, which has no audio);
    ``lookahead`` (phone and audio streams) is how many frames after frame t the phones or
    audio must cover before frame t comes; ``delay`` (audio streams) is the same in seconds.
    """

    type: Literal["start"] = "start"
    fps: float
    channels: list[str]
    sample_rate: int | None
    model: str
    lookahead: int | None = None
    delay: float | None = None


class FramesMessage(BaseModel):
    """Stream server message: consecutive frames from ``start_frame`` on, one row per frame over
    the start message's channels (frame k sits at k / fps seconds)."""

    type: Literal["frames"] = "frames"
    start_frame: int
    frames: list[list[float]]


class AudioMessage(BaseModel):
    """Stream server message: the next piece of audio, ``start`` seconds into the stream, as
    base64 16-bit little-endian mono PCM at the start message's sample rate."""

    type: Literal["audio"] = "audio"
    seq: int
    start: float
    pcm16: str


class ReplyMessage(BaseModel):
    """Stream server message of a chat: the next clause of the reply, as written (``text``), spoken
    in ``language`` from ``start`` seconds into the stream; ``session`` is the chat's session (send
    it with the next message)."""

    type: Literal["reply"] = "reply"
    session: str
    text: str
    language: str
    start: float


class EndMessage(BaseModel):
    """Stream server message, last of a stream: frames sent and seconds covered."""

    type: Literal["end"] = "end"
    n_frames: int
    duration: float


class CancelledMessage(BaseModel):
    """Listen server message, the answer to a ``cancel``: ``frames`` from ``start_frame`` on (rows
    over the start message's channels) ease the face from frame ``start_frame - 1`` (the cancel's
    ``frame``, or the last sent) to rest, to be shown at once in place of the frames after it;
    ``n_frames`` frames in all, ``duration`` seconds of audio received. A ``cancel`` with no
    stream to end (none yet, or the last already cancelled) gets one with no frames."""

    type: Literal["cancelled"] = "cancelled"
    start_frame: int
    frames: list[list[float]]
    n_frames: int
    duration: float


class WarningMessage(BaseModel):
    """Stream and listen server message: the stream goes on, but its frames are (or may be) late.

    ``too_fast`` (listen): the client sends audio faster than real time by a large factor, so
    the frames come as fast as the server computes them, not as live audio would; ``seconds``
    is how far the audio received leads real time. ``behind`` (listen): the server gave frames
    ``seconds`` after the audio they needed arrived. ``late`` (stream): a clause's audio and
    frames leave the server ``seconds`` after they are due, playback taken to start when the
    first audio chunk left (the server is overloaded: buffer more before playing, or come back
    later).
    """

    type: Literal["warning"] = "warning"
    code: Literal["too_fast", "behind", "late"]
    message: str
    seconds: float


class ErrorMessage(BaseModel):
    """Stream server message: what was wrong with the last client message (the connection stays open
    unless a close follows)."""

    type: Literal["error"] = "error"
    message: str


ServerMessage = TypeAdapter(
    Annotated[
        StartMessage
        | FramesMessage
        | AudioMessage
        | ReplyMessage
        | EndMessage
        | CancelledMessage
        | WarningMessage
        | ErrorMessage,
        Field(discriminator="type"),
    ]
)
"""Every message the server sends on ``/api/stream`` and ``/api/listen``; validates one (a dict or
JSON) into its model."""
