"""The speech service behind the server's routes: its models, cache, rate limit, work pool,
chat bot and chat sessions, and the calls into the library (no HTTP); the push batchers that run
the phone-stream and the live-audio pushes of all sessions together."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import os
import threading
from collections.abc import AsyncGenerator, Callable, Generator, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Generic, NamedTuple, TypeVar

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.align import TranscriptMismatch
from vispeech.frontends.audio import AudioClip, read_upload
from vispeech.frontends.espeak import check_voice, find_language
from vispeech.frontends.isolation import set_workers
from vispeech.frontends.sentiment import sentiment
from vispeech.frontends.text import detect_language
from vispeech.guards import TokenBucket
from vispeech.models.contract import Estimator
from vispeech.models.registry import PRETRAINED, RUNNABLE, load_model, model_version, pretrained_path
from vispeech.motion.formats.animation_json import ANIMATION_FORMAT
from vispeech.motion.formats.registry import track_text
from vispeech.motion.life import check_layers, with_life
from vispeech.motion.rigging.calibration import Calibration, load_scale
from vispeech.motion.track import Track
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL, GREETINGS, animate, listen, recording_model, speak
from vispeech.realtime import TimedSpeechStream
from vispeech.serve.bot import ChatBot, ChatBotError, ChatModel, ChatTurn
from vispeech.serve.cache import CachedUtterance, CacheKey, UtteranceCache
from vispeech.serve.chat import ReplyReader, SpokenClause, speak_reply
from vispeech.serve.clauses import ClauseBatcher
from vispeech.serve.config import ServeConfig
from vispeech.serve.pool import Busy, WorkPool
from vispeech.serve.safety import RateLimited, Slots
from vispeech.serve.schemas import (
    MAX_TEXT_CHARS,
    AnimateQuery,
    AnimationJSON,
    FramesMessage,
    Scale,
    SpeakResponse,
    SpeechOptions,
)
from vispeech.serve.sessions import ChatSessions
from vispeech.streaming import LiveAudioStream, PhoneStream, push_audio_together, push_together
from vispeech.text_stream import SpeechTimeline
from vispeech.turns import give_turn

log = logging.getLogger("vispeech.serve")

Said = str | Sequence[SpokenClause]
"""What an answer speaks: a text (in the request's language), or a chat reply's clauses (each in its own)."""
REPLY_LANGUAGE = "reply"
"""The language of the cache key of a reply's clauses (:data:`Said`), each spoken in its own."""

AnyStream = PhoneStream | LiveAudioStream | TimedSpeechStream
"""A stream whose frames the server sends: phones, live audio, or live audio with timings."""

LOW_LATENCY_MODEL = "grid-tdnn-lowlatency"
"""The shipped low-latency network (2 frames of look-ahead): what the stream uses unless told otherwise."""

TEXT_WORK_PER_CHAR = 4e-4
"""Estimated worker seconds per character of text spoken (the work pool's weight of a job)."""
PHONE_WORK_PER_SECOND = 0.03
"""Estimated worker seconds per second of phones pushed."""
AUDIO_WORK_PER_SECOND = 0.03
"""Estimated worker seconds per second of audio animated (an upload) or pushed (live audio)."""
MIN_CHUNK_SECONDS = 0.01
"""A live audio chunk is priced as at least this much audio (seconds), so floods of tiny chunks pay."""
LISTEN_SETTLE_TURNS = 8
"""Turns of the event loop the next batch of live audio pushes waits after a batch's frames are
handed out: a session answered takes four to push the chunks that came meanwhile (resume, send its
frames, take its waiting chunks, push them), and would otherwise wait a whole batch more."""


StreamT = TypeVar("StreamT", PhoneStream, LiveAudioStream)
ChunkT = TypeVar("ChunkT")
Together = Callable[[Sequence[tuple[StreamT, ChunkT]]], list[tuple[int, np.ndarray] | VispeechError]]
"""What pushes several streams at once: :func:`~vispeech.streaming.push_together` or
:func:`~vispeech.streaming.push_audio_together`."""


class _Push(NamedTuple, Generic[StreamT, ChunkT]):
    """A session's push waiting: its stream, chunk, output scale, estimated work (seconds) and
    the future of its frames."""

    stream: StreamT
    chunk: ChunkT
    scale: Calibration | None
    weight: float
    future: asyncio.Future


class PushBatcher(Generic[StreamT, ChunkT]):
    """Stream pushes of every session, batched: one pool job (of ``kind``, on behalf of ``key``)
    at a time runs the pushes waiting when a worker takes it, the first of each session, together
    (``together``: :func:`vispeech.streaming.push_together` takes one network step per frame for
    all the phone streams of a model, :func:`~vispeech.streaming.push_audio_together` one matrix
    product a layer for the new audio frames of all the audio streams of a network, instead of
    one each). Pushes made while the job waits for a worker join it; those made while it runs go
    with the next. With ``settle_turns``, the next job waits that many turns of the event loop
    after a job's frames are handed out, so that the sessions just answered, whose next chunks
    came while their push ran, push them in time to join it (a session takes a few turns to send
    its frames and take its waiting chunks) instead of waiting a whole job more.

    ``batches`` and ``pushes`` count what it ran, ``largest`` is the most pushes one batch held.
    """

    def __init__(
        self,
        service: SpeechService,
        kind: str,
        key: str,
        together: Together[StreamT, ChunkT],
        settle_turns: int = 0,
    ) -> None:
        self.service, self.kind, self.key = service, kind, key
        self.settle_turns = settle_turns
        self.together: Together[StreamT, ChunkT] = together
        self._waiting: list[_Push[StreamT, ChunkT]] = []
        self._lock = threading.Lock()  # the waiting list is taken in a worker thread
        self._busy = False  # a job is in the pool
        self.batches = self.pushes = self.largest = 0

    async def push(self, stream: StreamT, chunk: ChunkT, scale: Calibration | None, weight: float) -> str | None:
        """The ``frames`` message (in the output scale ``scale``) of ``stream.push(chunk)``, or None
        for no frames."""
        future = asyncio.get_running_loop().create_future()
        with self._lock:
            self._waiting.append(_Push(stream, chunk, scale, weight, future))
        if not self._busy:
            self._busy = True
            asyncio.ensure_future(self._run())
        return await future

    async def _run(self) -> None:
        while True:
            with self._lock:
                weight = sum(push.weight for push in self._waiting)
            try:
                batch, results = await self.service.pool.run(self.kind, self.key, self._frames, weight=weight)
            except BaseException as exc:  # Busy, shutting down: every session waiting is told
                with self._lock:
                    batch, self._waiting = self._waiting, []
                results = [exc] * len(batch)
            self.batches += 1
            self.pushes += len(batch)
            self.largest = max(self.largest, len(batch))
            for push, result in zip(batch, results):
                if push.future.done():
                    continue
                if isinstance(result, BaseException):
                    push.future.set_exception(result)
                else:
                    push.future.set_result(result)
            for _ in range(self.settle_turns):
                await asyncio.sleep(0)  # one turn: the sessions answered run to their next await
            with self._lock:
                if not self._waiting:
                    self._busy = False
                    return

    def _frames(self) -> tuple[list[_Push[StreamT, ChunkT]], list[str | None | Exception]]:
        """In a worker: the pushes waiting, the first of each session, and the ``frames`` message of
        each (``None`` for none), or its error, from ``together``."""
        batch: list[_Push[StreamT, ChunkT]] = []
        later: list[_Push[StreamT, ChunkT]] = []
        sessions: set[int] = set()
        with self._lock:
            for push in self._waiting:
                (later if id(push.stream) in sessions else batch).append(push)
                sessions.add(id(push.stream))
            self._waiting = later
        try:
            return batch, [
                result
                if isinstance(result, VispeechError)
                else self.service.frames_message(push.stream, push.scale, *result)
                for push, result in zip(batch, self.together([(push.stream, push.chunk) for push in batch]))
            ]
        except Exception as exc:  # noqa: BLE001 (every session of the batch is told)
            return batch, [exc] * len(batch)


class SpeechService:
    """The models, cache and bot behind the routes (the library calls, without HTTP)."""

    def __init__(self, config: ServeConfig) -> None:
        self.config = config
        self.calibration = load_scale(config.scale)
        check_voice(config.voice)
        self.models: dict[str, Estimator] = {}
        self.versions: dict[str, str] = {}
        for name in RUNNABLE:
            self._add(name, load_model(name), pretrained_path(name) if name in PRETRAINED else None)
        self.default_model = self._offer(config.default_model)
        """The name of the model of ``/api/speak`` and ``/api/chat`` (a saved folder is offered by its model's name)."""
        if self.models[self.default_model].input_kind != "phones":
            raise VispeechError(f"the default model must animate phones: {self.default_model} animates audio")
        self.stream_model = self._choose_stream_model(config.stream_model)
        self.audio_model = self._choose_audio_model(config.audio_model)
        self.upload_model = None if config.upload_model is None else self._offer(config.upload_model)
        self.cache = UtteranceCache(config.cache, config.cache_entries, config.cache_bytes)
        self.bucket = TokenBucket(config.rate_limit, config.burst)
        self.pool = WorkPool(config.workers, config.max_queue, config.max_wait)
        set_workers(max(config.workers, os.cpu_count() or 1))  # native work (espeak-ng, ...): one process a core
        self.pushes = PushBatcher(self, "phones", "phone streams", push_together)
        """The phone streams' pushes (``/api/stream``)."""
        self.clauses = ClauseBatcher(self.pool, self.models, "text", "text streams")
        """The text streams' clauses (``/api/stream``), voiced in the native workers."""
        self.listens = PushBatcher(self, "listen", "listen streams", push_audio_together, LISTEN_SETTLE_TURNS)
        """The live audio streams' pushes (``/api/listen`` without timings)."""
        self.connections = Slots(config.max_streams, config.max_streams_per_ip, config.max_streams_per_network)
        self.chats = ChatSessions(
            config.chat_sessions, config.chat_history, config.chat_history_chars, config.chat_session_seconds
        )
        self.reply_languages = [find_language(code).code for code in config.reply_languages]
        self.chat_threads = ThreadPoolExecutor(config.max_chats, "vispeech-chat")  # waiting on the chat model
        self.chatting = 0
        """Chat replies the server waits on now (at most ``max_chats``)."""

    @property
    def active_streams(self) -> int:
        return self.connections.total

    @property
    def chat_languages(self) -> list[str] | None:
        """The languages the chat bot answers in (``None``: any, or it does not say)."""
        languages = getattr(self.config.bot, "languages", None)
        return None if languages is None else list(languages)

    def text_cost(self, text: str) -> float:
        """Rate-limit tokens a text costs: one per ``chars_per_token`` characters, at least one."""
        return max(1.0, len(text) / self.config.chars_per_token)

    def audio_cost(self, seconds: float) -> float:
        """Rate-limit tokens an uploaded recording costs: one per ``audio_seconds_per_token`` seconds, at least one."""
        return max(1.0, seconds / self.config.audio_seconds_per_token)

    def pay(self, key: str, cost: float) -> None:
        """Spend ``cost`` of client ``key``'s tokens; :class:`RateLimited` when it has too few."""
        if not self.bucket.take(key, cost):
            raise RateLimited(self.bucket)

    def _add(self, name: str, model: Estimator, folder: Path | None = None) -> None:
        """Offer ``model`` as ``name``; its version digests its parameters (and its saved folder's files)."""
        self.models[name] = model
        self.versions[name] = model_version(model, folder)

    def scale(self, name: Scale | None) -> tuple[str, Calibration | None]:
        """The output scale ``name`` (``None``: the server's): a digest of its gains (what the cache
        keys it by, so a cached answer is never of another scale) and its calibration."""
        calibration = self.calibration if name is None else load_scale(name)
        gains = {} if calibration is None else calibration.gains
        return hashlib.sha256(json.dumps(gains, sort_keys=True).encode()).hexdigest()[:8], calibration

    def frames_message(self, stream: AnyStream, scale: Calibration | None, start: int, rows: np.ndarray) -> str | None:
        """Frames of a stream from ``start``, in the output scale ``scale`` (a calibration of
        :meth:`scale`), as a ``frames`` message (``None`` for none)."""
        if not len(rows):
            return None
        rows = scaled(rows, stream, scale)
        return FramesMessage(start_frame=start, frames=rows.round(6).tolist()).model_dump_json()

    def step(self, stream: AnyStream, scale: Calibration | None, step: Callable, *args) -> str | None:
        """Run a phone or audio stream's ``push`` / ``finish``: its frames as a :meth:`frames_message`."""
        return self.frames_message(stream, scale, *step(*args))

    def _choose_stream_model(self, spec: str | None) -> str:
        if spec is None:
            if LOW_LATENCY_MODEL in self.models:
                return LOW_LATENCY_MODEL
            log.info("%s is not trained: streaming uses %s", LOW_LATENCY_MODEL, self.default_model)
            return self.default_model
        return self._offer(spec)

    def _choose_audio_model(self, spec: str | None) -> str | None:
        if spec is None:
            return None
        if spec == DEFAULT_AUDIO_STREAM_MODEL and spec not in self.models:
            log.info("%s is not installed: no audio model (start the server with --audio-model)", spec)
            return None
        name = self._offer(spec)
        if self.models[name].input_kind != "audio":
            raise VispeechError(f"the audio model must animate audio: {name} animates phones")
        try:
            self.models[name].stream(None, self.config.fps).close()  # type: ignore[arg-type]  # audio: no language
        except VispeechError as exc:
            raise VispeechError(f"the audio model must stream live audio: {exc}") from None
        return name

    def _offer(self, spec: str) -> str:
        """The name of model ``spec``: one offered already, or a trained model's folder, loaded and offered."""
        if spec in self.models:
            return spec
        model = load_model(spec)
        model.check_fitted()
        folder = Path(spec)
        name = model.name if model.name not in self.models else f"{model.name}:{folder.name}"
        self._add(name, model, folder)
        return name

    def warm_up(self) -> None:
        """Load espeak-ng's voices, the language identifier (a chat reply's sentences are told apart
        on the event loop) and run the default, stream, upload (English and Swedish) and audio models
        once, and the stream model in each native worker, so a first request is no slower."""
        for language, text in GREETINGS.items():
            utterance = speak(text, language, model=self.models[self.default_model], fps=self.config.fps)
            assert utterance.phones is not None  # speak gives the phones it spoke
            detect_language(text, self.reply_languages)
            with contextlib.suppress(VispeechError):  # a trained stream model may know one language only
                animate(utterance.phones, self.models[self.stream_model], self.config.fps)
                timeline = SpeechTimeline(self.models[self.stream_model], fps=self.config.fps)
                self.clauses.warm_up(self.stream_model, timeline.clause(text, language, last=True))
        for name in dict.fromkeys(self.upload_model or recording_model(False, language) for language in GREETINGS):
            upload = self.models[name]
            if upload.input_kind == "audio":  # Whisper's encoder loads on its first clip
                upload.predict(AudioClip.from_array(np.zeros(16_000, np.float32), 16_000), self.config.fps)
        if self.audio_model is not None:
            stream = LiveAudioStream(self.models[self.audio_model], 48_000, self.config.fps)
            stream.push(bytes(48_000))
            stream.finish()

    def model(self, name: str | None, stream: bool = False, audio: bool = False) -> tuple[str, Estimator]:
        """The model called ``name`` (``None``: the default; the stream model when ``stream``, the audio
        model when ``audio``)."""
        if name is None and audio:
            if self.audio_model is None:
                raise VispeechError(
                    "this server has no audio model: name one (model), or start the server "
                    "with --audio-model NAME|FOLDER"
                )
            name = self.audio_model
        name = name or (self.stream_model if stream else self.default_model)
        if name not in self.models:
            raise VispeechError(f"unknown model {name!r} (use one of: {', '.join(self.models)})")
        return name, self.models[name]

    def _key(self, said: Said, options: SpeechOptions) -> tuple[CacheKey, Estimator, Calibration | None]:
        name, model = self.model(options.model)
        voice = options.voice or self.config.voice
        if isinstance(said, str):
            spoken = find_language(options.language)
            text, language = said, spoken.code
            selector = spoken.selector if voice is None else f"{spoken.selector}+{voice}"
        else:  # a reply's clauses, each in its language: apart from any text's entry
            text = "\n".join(f"{clause.language}\t{clause.spoken}" for clause in said)
            language, selector = REPLY_LANGUAGE, voice or ""
        fps = options.fps or self.config.fps
        scale, calibration = self.scale(options.scale)
        key = CacheKey(text, language, selector, float(options.rate), name, self.versions[name], fps, scale)
        return key, model, calibration

    def lookup(self, said: Said, options: SpeechOptions) -> SpeakResponse | None:
        """The cached answer to speaking ``said`` so, or ``None`` (nothing computed)."""
        key, _, calibration = self._key(said, options)
        entry = self.cache.get(key)
        return None if entry is None else self._answer(entry, _written(said), True, calibration, options)

    def speak(self, said: Said, options: SpeechOptions) -> SpeakResponse:
        """The answer to speaking ``said`` so, from the cache when the same request was answered before.

        A text is spoken whole in ``options.language``; a reply's clauses each in its own, as
        the stream speaks them (:func:`~vispeech.serve.chat.speak_reply`: no phones in the answer,
        since they are of several phone sets). The cache holds the speech alone; the non-verbal
        layers ``options.life`` are added to each answer, so every seed shares the speech's entry
        and its audio."""
        key, model, calibration = self._key(said, options)
        entry = self.cache.get(key)
        cached = entry is not None
        if entry is None:
            voice = options.voice or self.config.voice
            if isinstance(said, str):
                utterance = speak(said, options.language, model=model, rate=options.rate, fps=key.fps, voice=voice)
                wav = utterance.wav_bytes()
                assert wav is not None and utterance.track is not None  # speak gives the audio and track
                animation = _animation_json(utterance.track, utterance.phones, calibration)
            else:
                wav, track = speak_reply(said, model, fps=key.fps, rate=options.rate, scale=calibration, voice=voice)
                animation = _animation_json(track, None)  # in the scale already
            entry = self.cache.put(key, wav, animation)
        return self._answer(entry, _written(said), cached, calibration, options)

    def _upload_key(self, digest: str, query: AnimateQuery) -> tuple[CacheKey, Estimator, Calibration | None]:
        """An upload's cache key: its voice is ``upload:<the SHA-256 of the file>`` (``:forced`` added
        for a transcript taken whether it fits or not)."""
        default = self.upload_model or recording_model(query.text is not None, query.language)
        name, model = self.model(query.model or default)
        fps = query.fps or self.config.fps
        scale, calibration = self.scale(query.scale)
        voice = f"upload:{digest}:forced" if query.force else f"upload:{digest}"
        key = CacheKey(query.text or "", query.language, voice, 1.0, name, self.versions[name], fps, scale)
        return key, model, calibration

    def lookup_upload(self, digest: str, query: AnimateQuery) -> SpeakResponse | None:
        """The cached answer for this upload, or ``None`` (nothing computed)."""
        key, _, calibration = self._upload_key(digest, query)
        entry = self.cache.get(key)
        return None if entry is None else self._answer(entry, query.text or "", True, calibration, query)

    def animate_upload(self, data: bytes, digest: str, query: AnimateQuery) -> SpeakResponse:
        """The answer for an uploaded recording (``data``, the file's bytes):
        :func:`vispeech.pipeline.listen`, from the cache when the same file came with the same options."""
        key, model, calibration = self._upload_key(digest, query)
        entry = self.cache.get(key)
        cached = entry is not None
        if entry is None:
            try:
                utterance = listen(
                    read_upload(data), query.text, query.language, model=model, fps=key.fps, force=query.force
                )
            except TranscriptMismatch as exc:
                raise VispeechError(f"{exc} (force=true: animate it all the same)") from None
            give_turn()
            wav = utterance.wav_bytes()
            assert wav is not None and utterance.track is not None  # listen keeps the audio it animated
            entry = self.cache.put(key, wav, _animation_json(utterance.track, utterance.phones, calibration))
            give_turn()
        return self._answer(entry, query.text or "", cached, calibration, query)

    def _answer(
        self,
        entry: CachedUtterance,
        text: str,
        cached: bool,
        calibration: Calibration | None,
        options: SpeechOptions | AnimateQuery,
    ) -> SpeakResponse:
        """A cache entry as the answer to ``text`` (in ``options.language``), with the non-verbal
        layers of ``options`` added (timed by its phones, the expression showing ``text``'s mood,
        in the output scale ``calibration``) and the files of the formats it asks for."""
        animation = AnimationJSON.model_validate_json(entry.animation)
        if not options.life and not options.formats:
            return SpeakResponse(audio_url=f"/api/audio/{entry.id}.wav", animation=animation, text=text, cached=cached)
        data = animation.model_dump()
        phones = PhoneSequence.from_dict(data["phones"]) if data["phones"] else None
        track = Track.from_dict(data)
        if options.life:
            layers = check_layers(options.life)
            mood = sentiment(text, options.language)
            track = with_life(track, phones, layers, options.seed, scale=calibration, mood=mood)
            animation = AnimationJSON.model_validate({**data, **track.to_dict()})
        files = {fmt: track_text(track, fmt, phones=phones) for fmt in dict.fromkeys(options.formats)}
        return SpeakResponse(
            audio_url=f"/api/audio/{entry.id}.wav", animation=animation, text=text, cached=cached, files=files
        )

    def _reply(self, bot: ChatBot, message: str, language: str) -> tuple[str, str]:
        """The reply of a :class:`~vispeech.serve.bot.ChatBot` to ``message`` (stripped, cut to
        :data:`MAX_TEXT_CHARS`) and the language it was asked in: the page's (``language``), or for a
        bot with a list of languages (the rule bot) the one the message is written in, when
        :func:`~vispeech.frontends.text.detect_language` can tell."""
        answered = self.chat_languages
        asked = language
        if answered is not None:
            asked = detect_language(message, answered) or language
        reply = bot.reply(message, asked)
        if not isinstance(reply, str) or not reply.strip():
            raise ChatBotError("the chat bot gave no reply")
        return reply.strip()[:MAX_TEXT_CHARS], asked

    async def chat(self, message: str, language: str, session: str) -> AsyncGenerator[SpokenClause, None]:
        """The bot's reply to ``message`` (in a chat on a page in ``language``), clause by clause as it
        is written, each with the language of its sentence (:class:`~vispeech.serve.chat.ReplyReader`
        among ``reply_languages``); a chat model is told ``session``'s conversation, and the exchange
        is kept in it once the reply has ended. The reply is cut to :data:`MAX_TEXT_CHARS`."""
        bot = self.config.bot
        if not isinstance(bot, ChatModel):
            reply, asked = await asyncio.get_running_loop().run_in_executor(
                self.chat_threads, self._reply, bot, message, language
            )
            reader = ReplyReader(self.reply_languages, asked)
            for clause in [*reader.feed(reply), *reader.finish()]:
                yield clause
            self.chats.add(session, message, reply)
            return
        if self.chatting >= self.config.max_chats:
            raise Busy(f"the server is answering {self.chatting} chats, the most it may: try again shortly")
        self.chatting += 1
        loop = asyncio.get_running_loop()
        conversation = [*self.chats.history(session), ChatTurn("user", message)]
        reader, reply = ReplyReader(self.reply_languages, language), ""
        pieces: Iterator[str] = iter(())
        try:
            pieces = await loop.run_in_executor(self.chat_threads, bot.stream, conversation)
            while len(reply) < MAX_TEXT_CHARS:
                piece = await loop.run_in_executor(self.chat_threads, next, pieces, None)
                if piece is None:
                    break
                piece = piece[: MAX_TEXT_CHARS - len(reply)]
                reply += piece
                for clause in reader.feed(piece):
                    yield clause
            for clause in reader.finish():
                yield clause
            self.chats.add(session, message, reply)
        except ChatBotError as exc:
            log.warning("the chat model %r failed: %s", bot, exc)
            raise
        finally:
            self.chatting -= 1
            if isinstance(pieces, Generator):
                with contextlib.suppress(ValueError):  # still reading in its thread: dropped, closed when collected
                    pieces.close()


def scaled(rows: np.ndarray, stream: AnyStream, scale: Calibration | None) -> np.ndarray:
    """Frames of ``stream`` (rows over its channels) in the output scale ``scale`` (``None``: the
    models' own)."""
    if scale is None or not len(rows):
        return rows
    return scale.apply(Track(rows, stream.channels, stream.fps)).values


def _animation_json(track: Track, phones: PhoneSequence | None, calibration: Calibration | None = None) -> str:
    """A track (in ``calibration``'s scale) and its phones (when there are) as compact vispeech
    animation JSON."""
    track = track if calibration is None else calibration.apply(track)
    animation = {
        "format": ANIMATION_FORMAT,
        "version": 1,
        **track.to_dict(),
        "phones": None if phones is None else phones.to_dict(),
    }
    return json.dumps(animation, separators=(",", ":"))


def _written(said: Said) -> str:
    """What an answer says it spoke: the text, or the reply's clauses as written."""
    return said if isinstance(said, str) else " ".join(clause.text for clause in said)
