"""The server's settings, :class:`ServeConfig`: every default of ``vispeech serve`` and of
:func:`~vispeech.serve.create_app`, and the JSON they travel in to the server's other processes."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from urllib.parse import urlsplit

from vispeech.errors import VispeechError
from vispeech.guards import DEFAULT_ALLOWED_HOSTS
from vispeech.motion.rigging.head import DEFAULT_HEAD, HEAD_CREDIT
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL, DEFAULT_FPS, DEFAULT_MODEL, DEFAULT_SCALE
from vispeech.serve.bot import ChatBot, ChatModel, RuleBot
from vispeech.serve.llm import OpenAIChatBot
from vispeech.serve.schemas import MAX_STREAM_SECONDS

_MIB = 1024 * 1024
"""Bytes in a mebibyte."""


def _default_workers() -> int:
    return max(1, (os.cpu_count() or 2) - 1)


@dataclass(frozen=True)
class Option:
    """How ``vispeech serve`` sets a :class:`ServeConfig` field; the option's default is the field's.

    ``name``: the option (``--rate-limit``); ``minimum``: the least number it takes; ``unit``: it
    counts in units of this many of the field's (``--cache-mb``: MiB of ``cache_bytes``);
    ``envvar``: where it is read from when not given; ``negated``: a flag that sets a true field
    false (``--avatar-as-is``); ``url``: a file or an http(s) URL, taken as text (``--avatar``).
    """

    name: str
    help: str
    minimum: float | None = None
    unit: int = 1
    envvar: str | None = None
    negated: bool = False
    url: bool = False


def is_url(value: str) -> bool:
    """Whether ``value`` is an http(s) URL with a host (anything else is a file name)."""
    parts = urlsplit(value)
    return parts.scheme in ("http", "https") and bool(parts.netloc)


def _option(name: str, help: str, **more) -> dict[str, Option]:
    """A field's metadata: the :class:`Option` that sets it from the command line."""
    return {"option": Option(name, help, **more)}


@dataclass
class ServeConfig:
    """Server settings, with every default of the server; a field with an :class:`Option` in its
    metadata is a ``vispeech serve`` option as well.

    ``cache``: SQLite file of the utterance cache (``None``: the user cache folder,
    ``":memory:"``: none kept). ``stream_model``: model name or saved folder the stream uses
    when a message names none; ``None`` picks the shipped ``grid-tdnn-lowlatency`` if it is there and
    otherwise ``default_model``. ``audio_model``: model name or saved folder of the audio model
    that animates live audio (``/api/listen``) when a request names none; the shipped
    ``grid-audio-cnn`` by default, and when that is not installed (or ``None``) there is none and
    those requests must name one. ``upload_model``: model name or saved folder that animates
    recordings (``/api/animate``) when a request names none; ``None``: what ``vispeech animate``
    takes (:func:`vispeech.pipeline.recording_model`). ``rate_limit``:
    tokens a second per client IP (0 = no limit), with bursts of ``burst``; a request or stream
    message costs a token per ``chars_per_token`` characters of text (at least one), per
    ``phone_seconds_per_token`` seconds of phones it adds (at least ``min_message_cost``) or per
    ``audio_seconds_per_token`` seconds of audio (an upload at least one token, a live chunk at
    least :data:`~vispeech.serve.service.MIN_CHUNK_SECONDS`); a spoken chat reply is charged after the fact. Sizes are
    bytes. ``static_dir``: the built web app (default
    :data:`~vispeech.serve.pages.STATIC_DIR`). ``avatar``: the head the pages show, a GLB or VRM file
    (``None``: the shipped :data:`~vispeech.motion.rigging.head.DEFAULT_HEAD`) or an http(s) URL the
    browser loads it from (the server fetches nothing; a string that is not such a URL is a file
    name); ``head``: ``False`` shows the built-in 2D face instead. ``avatar_credit``: a line the pages
    show under the head (its author and licence; the shipped head's by default, a VRM's meta else).
    ``prepare_avatar``: serve an ``avatar`` file with the tongue morph targets and painted looks it
    lacks (:func:`vispeech.motion.rigging.head.prepared_head`, done once when the app is made);
    ``False`` serves the file as it is.

    Abuse: ``workers`` threads run the CPU-heavy work (speech, stream clauses, phone pushes
    in pieces of ``piece_seconds``), the native libraries' part of it in as many worker processes
    (:mod:`vispeech.frontends.isolation`), with at most ``max_wait`` seconds of estimated work
    waiting for each worker and at most ``max_queue`` jobs (503 / stream error beyond, but to a
    kind of work holding less than its share), taken fairly between kinds of work, clients and
    their sessions (:class:`~vispeech.serve.pool.WorkPool`). ``max_streams`` WebSocket
    connections at once, ``max_streams_per_ip`` of them from one address and
    ``max_streams_per_network`` from one /24 (IPv4) or /64 (IPv6); a connection that finds the
    server full takes the place of the one idle longest (2 s at least). Each closes after ``idle_timeout`` s
    without valid work (an invalid or refused message does not count) while nothing is being
    computed, and after ``stream_timeout`` s in all. A phones message may add
    at most ``max_message_seconds`` s of phones, a phone or audio stream reach ``max_stream_seconds``.
    Audio: an upload's body may have ``max_audio_bytes``, a live chunk ``max_chunk_bytes``; a live
    client that sends audio faster than ``max_audio_speed`` times real time is warned
    (``too_fast``), and so is one whose frames leave more than ``max_audio_lag`` s after their
    audio arrived (``behind``); the server reads no more of a connection's audio while
    ``max_audio_backlog`` s of it wait (TCP then slows the client).
    ``allowed_hosts`` / ``allowed_origins``: see :class:`~vispeech.guards.HostOriginCheck`;
    ``token``: see :class:`~vispeech.serve.safety.TokenAuth` (``None``: no token wanted).
    ``cache_bytes`` caps the cache's size.

    Chat: ``bot`` answers ``/api/chat`` and the stream's chat messages (a
    :class:`~vispeech.serve.bot.ChatBot`, or a :class:`~vispeech.serve.bot.ChatModel` such as
    :class:`~vispeech.serve.llm.OpenAIChatBot`, told its session's last ``chat_history`` exchanges
    within ``chat_history_chars`` characters); at most ``chat_sessions`` sessions are kept, each
    dropped ``chat_session_seconds`` after its last use, and ``max_chats`` replies awaited at once.
    Each sentence of a reply is spoken in the one of ``reply_languages`` (or the page's language)
    it is written in. ``switch_interval``: the GIL switch interval the
    server sets when it starts (seconds; ``None`` leaves Python's 5 ms), so the event loop wins
    the GIL back quickly from a busy worker after each socket call.
    """

    avatar: Path | str | None = field(
        default=None,
        metadata=_option(
            "--avatar",
            "The head: a glTF binary (.glb) or VRM file, served as /avatar.glb with the tongue morph targets "
            "and painted looks it lacks (vispeech rig prepare), or an http(s) URL the browser loads it from "
            "(the server downloads nothing) [default: the shipped ICT-FaceKit head].",
            url=True,
        ),
    )
    head: bool = field(
        default=True,
        metadata=_option("--face-2d", "Show the built-in 2D face instead of a 3D head.", negated=True),
    )
    avatar_credit: str | None = field(
        default=None,
        metadata=_option(
            "--avatar-credit",
            "Credit line shown under the head, its author and licence [default: the shipped head's].",
        ),
    )
    prepare_avatar: bool = field(
        default=True,
        metadata=_option(
            "--avatar-as-is", "Serve --avatar untouched (no tongue targets or paint added).", negated=True
        ),
    )
    cache: str | os.PathLike | None = field(
        default=None,
        metadata=_option(
            "--cache", "SQLite file of the utterance cache [default: serve.sqlite3 in ~/.cache/vispeech]."
        ),
    )
    cache_entries: int = 10_000
    cache_bytes: int = field(
        default=512 * _MIB,
        metadata=_option(
            "--cache-mb", "Largest size of the utterance cache (MiB of audio and animation).", minimum=1, unit=_MIB
        ),
    )
    bot: ChatBot | ChatModel = field(default_factory=RuleBot)
    reply_languages: tuple[str, ...] = ("en", "sv")
    chat_history: int = field(
        default=10,
        metadata=_option(
            "--chat-history", "Exchanges (a message and its reply) a chat session keeps for the chat model.", minimum=0
        ),
    )
    chat_history_chars: int = 8000
    chat_sessions: int = 1000
    chat_session_seconds: float = 1800.0
    max_chats: int = field(
        default=16,
        metadata=_option(
            "--max-chats", "Chat replies the server waits on at once; beyond that chats get 503 (busy).", minimum=1
        ),
    )
    default_model: str = field(
        default=DEFAULT_MODEL, metadata=_option("--model", "Default model of /api/speak and /api/chat.")
    )
    stream_model: str | None = field(
        default=None,
        metadata=_option(
            "--stream-model",
            "Model name or saved model folder for /api/stream [default: the shipped grid-tdnn-lowlatency].",
        ),
    )
    audio_model: str | None = field(
        default=DEFAULT_AUDIO_STREAM_MODEL,
        metadata=_option(
            "--audio-model",
            "Audio model name or saved folder for /api/listen (none when the default is not installed).",
        ),
    )
    upload_model: str | None = field(
        default=None,
        metadata=_option(
            "--upload-model",
            "Model name or saved folder for /api/animate [default: as `vispeech animate`: "
            "grid-audio-whisper-ensemble with the whisper extra, and grid-audio-whisper blended with grid-tdnn "
            "on an English transcript's phones; else grid-audio-encdec, or grid-tdnn with a transcript].",
        ),
    )
    fps: float = DEFAULT_FPS
    rate_limit: float = field(
        default=2.0,
        metadata=_option(
            "--rate-limit", "Requests a second per client IP for speak, chat and stream texts (0: no limit).", minimum=0
        ),
    )
    burst: int = field(default=20, metadata=_option("--burst", "Requests a client may make at once.", minimum=1))
    max_body_bytes: int = 64 * 1024
    max_message_bytes: int = 64 * 1024
    max_audio_bytes: int = 32 * _MIB
    max_chunk_bytes: int = 32 * 1024
    max_streams: int = field(
        default=500, metadata=_option("--max-streams", "WebSocket connections open at once.", minimum=1)
    )
    max_streams_per_ip: int = field(
        default=8,
        metadata=_option(
            "--max-streams-per-ip", "WebSocket connections open at once from one client address.", minimum=1
        ),
    )
    max_streams_per_network: int = field(
        default=32,
        metadata=_option(
            "--max-streams-per-network",
            "WebSocket connections open at once from one network (an IPv4 /24, an IPv6 /64).",
            minimum=1,
        ),
    )
    idle_timeout: float = field(
        default=30.0,
        metadata=_option(
            "--idle-timeout",
            "Seconds a WebSocket may stay silent (with nothing being computed) before it is closed.",
            minimum=0.1,
        ),
    )
    stream_timeout: float = field(
        default=600.0,
        metadata=_option("--stream-timeout", "Seconds a WebSocket connection may stay open in all.", minimum=1),
    )
    max_message_seconds: float = 20.0
    max_stream_seconds: float = MAX_STREAM_SECONDS
    chars_per_token: float = 100.0
    phone_seconds_per_token: float = 1.0
    min_message_cost: float = 0.05
    audio_seconds_per_token: float = 4.0
    max_audio_speed: float = 4.0
    max_audio_lag: float = 0.5
    max_audio_backlog: float = 2.0
    workers: int = field(
        default_factory=_default_workers,
        metadata=_option("--workers", "Threads for the CPU-heavy work [default: cores - 1].", minimum=1),
    )
    max_wait: float = field(
        default=2.0,
        metadata=_option(
            "--max-wait",
            "Estimated seconds of work that may wait for each worker; beyond that requests get 503 (busy).",
            minimum=0.01,
        ),
    )
    max_queue: int = field(
        default=1024,
        metadata=_option(
            "--max-queue",
            "Jobs that may wait for a worker, however small; beyond that requests get 503 (busy).",
            minimum=1,
        ),
    )
    piece_seconds: float = 1.0
    switch_interval: float | None = 0.0005
    allowed_hosts: tuple[str, ...] = DEFAULT_ALLOWED_HOSTS
    allowed_origins: tuple[str, ...] | None = None
    token: str | None = field(
        default=None,
        metadata=_option(
            "--token",
            "Require this bearer token for the API and the stream (pages and /api/config stay open; open a "
            "page with ?token=... to let it in).",
            envvar="VISPEECH_TOKEN",
        ),
    )
    static_dir: Path | None = None
    scale: str = DEFAULT_SCALE
    voice: str | None = field(
        default=None,
        metadata=_option(
            "--voice",
            "The avatar's voice: f1-f5 female, m1-m8 male, ... (`vispeech languages --voices`).",
        ),
    )

    def __post_init__(self) -> None:
        if isinstance(self.avatar, str) and not is_url(self.avatar):
            scheme = urlsplit(self.avatar).scheme
            if "://" in self.avatar and scheme:  # ftp://, file://, s3://: no file name and no page loads it
                raise VispeechError(f"--avatar takes a GLB or VRM file or an http(s) URL, not a {scheme}:// URL")
            self.avatar = Path(self.avatar)

    @property
    def avatar_link(self) -> str | None:
        """The URL the browser loads the head from when ``avatar`` is one, else ``None``."""
        return self.avatar if isinstance(self.avatar, str) else None

    @property
    def head_file(self) -> Path | None:
        """The GLB or VRM head the server serves: ``avatar``, else the shipped head; ``None`` for the 2D
        face and for a head at a URL."""
        if not self.head or isinstance(self.avatar, str):
            return None
        return DEFAULT_HEAD if self.avatar is None else Path(self.avatar)

    @property
    def head_credit(self) -> str | None:
        """The line shown under the head: ``avatar_credit``, else the shipped head's when it is shown."""
        if self.avatar_credit is not None or not self.head:
            return self.avatar_credit
        return HEAD_CREDIT if self.avatar is None else None

    def to_json(self) -> str:
        """The settings as JSON, for the server's other processes (:func:`~vispeech.serve.app.app_from_environment`).

        Raises :class:`VispeechError` for a chat bot other than the rule bot or an OpenAI-compatible one."""
        data = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "bot"}
        data = {k: str(v) if isinstance(v, Path) else list(v) if isinstance(v, tuple) else v for k, v in data.items()}
        bot = self.bot
        if isinstance(bot, OpenAIChatBot):
            data["bot"] = bot.settings()
        elif type(bot) is RuleBot:
            data["bot"] = None
        else:
            raise VispeechError(f"the chat bot {bot!r} cannot be handed to other server processes")
        return json.dumps(data)

    @classmethod
    def from_json(cls, text: str) -> ServeConfig:
        """The settings :meth:`to_json` wrote."""
        data = json.loads(text)
        bot = data.pop("bot")
        data["static_dir"] = None if data["static_dir"] is None else Path(data["static_dir"])
        for key in ("allowed_hosts", "allowed_origins", "reply_languages"):
            data[key] = None if data[key] is None else tuple(data[key])
        return cls(**data, bot=RuleBot() if bot is None else OpenAIChatBot(**bot))


CONFIG_VARIABLE = "VISPEECH_SERVE_CONFIG"
"""The environment variable through which ``vispeech serve --processes N`` hands its settings
(:meth:`ServeConfig.to_json`) to each server process."""
