"""``vispeech serve``: the web server (chat page, players, speak / chat / stream APIs)."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main, scale_option
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL, DEFAULT_MODEL


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (0.0.0.0: every interface).")
@click.option("--port", default=8000, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option("--avatar", type=click.Path(path_type=Path, dir_okay=False),
              help="glTF binary head served as /avatar.glb, with the tongue morph targets and painted looks it "
              "lacks (vispeech rig prepare).")
@click.option("--avatar-as-is", is_flag=True, help="Serve --avatar untouched (no tongue targets or paint added).")
@click.option("--avatar-credit",
              help='Credit line shown under the head, e.g. "3D head: ICT-FaceKit (USC ICT), MIT licence".')
@click.option("--cache", type=click.Path(path_type=Path, dir_okay=False),
              help="SQLite file of the utterance cache [default: serve.sqlite3 in ~/.cache/vispeech].")
@click.option("--model", "default_model", default=DEFAULT_MODEL, show_default=True,
              help="Default model of /api/speak and /api/chat.")
@click.option("--stream-model", help="Model name or saved model folder for /api/stream "
              "[default: the shipped grid-tdnn-lowlatency].")
@click.option("--audio-model", default=DEFAULT_AUDIO_STREAM_MODEL, show_default=True,
              help="Audio model name or saved folder for /api/listen and /api/animate without a transcript "
              "(none when the default is not installed).")
@click.option("--rate-limit", default=2.0, show_default=True, type=click.FloatRange(min=0),
              help="Requests a second per client IP for speak, chat and stream texts (0: no limit).")
@click.option("--burst", default=20, show_default=True, type=click.IntRange(min=1),
              help="Requests a client may make at once.")
@click.option("--chat-url",
              help="External chat service to relay /api/chat messages to (POST JSON) instead of the rule bot.")
@click.option("--chat-reply-field", default="reply", show_default=True,
              help="Where the chat service's JSON answer holds the reply (dotted path: choices.0.message.content).")
@click.option("--token", envvar="VISPEECH_TOKEN", show_envvar=True,
              help="Require this bearer token for the API and the stream (pages and /api/config stay open; "
              "open a page with ?token=... to let it in).")
@click.option("--allow-host", multiple=True, metavar="NAME",
              help="Host name the server answers to, beside localhost, 127.0.0.1, ::1, --host and IP addresses "
              "(repeatable; * for any). Other Host headers get 400 (DNS rebinding).")
@click.option("--allow-origin", multiple=True, metavar="ORIGIN",
              help="Browser origin (https://app.example.com, or a host name) allowed to use the API and the "
              "stream, beside the server's own and the allowed hosts (repeatable; * for any). Others get 403.")
@click.option("--workers", type=click.IntRange(min=1), help="Threads for the CPU-heavy work [default: cores - 1].")
@click.option("--processes", default=1, show_default=True, type=click.IntRange(min=1),
              help="Server processes sharing the port and the SQLite cache, each with its models and threads "
              "(limits count per process).")
@click.option("--max-queue", default=64, show_default=True, type=click.IntRange(min=1),
              help="Jobs that may wait for a worker; beyond that requests get 503 (busy).")
@click.option("--max-streams", default=500, show_default=True, type=click.IntRange(min=1),
              help="WebSocket connections open at once.")
@click.option("--max-streams-per-ip", default=8, show_default=True, type=click.IntRange(min=1),
              help="WebSocket connections open at once from one client address.")
@click.option("--idle-timeout", default=30.0, show_default=True, type=click.FloatRange(min=0.1),
              help="Seconds a WebSocket may stay silent (with nothing being computed) before it is closed.")
@click.option("--stream-timeout", default=600.0, show_default=True, type=click.FloatRange(min=1),
              help="Seconds a WebSocket connection may stay open in all.")
@click.option("--cache-mb", default=512, show_default=True, type=click.IntRange(min=1),
              help="Largest size of the utterance cache (MiB of audio and animation).")
@click.option("--ws-deflate/--no-ws-deflate", default=False, show_default=True,
              help="Compress WebSocket messages (permessage-deflate): less traffic, more CPU per message.")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["critical", "error", "warning", "info", "debug"]), help="Server log level.")
@scale_option("arkit")
@click.option("--voice", "variant", default=None,
              help="The avatar's espeak-ng voice variant: f1-f5 female, m1-m8 male, ... (`vispeech languages --variants`).")
def serve(host: str, port: int, avatar: Path | None, avatar_credit: str | None, avatar_as_is: bool, cache: Path | None,
          default_model: str, stream_model: str | None, audio_model: str, rate_limit: float, burst: int,
          chat_url: str | None, chat_reply_field: str, token: str | None, allow_host: tuple[str, ...],
          allow_origin: tuple[str, ...],
          workers: int | None, processes: int, max_queue: int, max_streams: int, max_streams_per_ip: int, idle_timeout: float,
          stream_timeout: float, cache_mb: int, ws_deflate: bool, log_level: str, scale: str,
          variant: str | None) -> None:
    """Serve the chat page at http://HOST:PORT/, the players and the JSON / WebSocket APIs.

    API documentation is at /docs; docs/serve.md lists the limits. Stop with Ctrl+C.
    """
    import uvicorn

    from vispeech.serve import HTTPChatBot, RuleBot, ServeConfig, create_app

    bot = HTTPChatBot(chat_url, reply_field=chat_reply_field) if chat_url else RuleBot()
    hosts = ("localhost", "127.0.0.1", "::1", *([host] if host not in ("0.0.0.0", "::", "") else []), *allow_host)
    extra = {} if workers is None else {"workers": workers}
    config = ServeConfig(avatar=avatar, avatar_credit=avatar_credit, prepare_avatar=not avatar_as_is, cache=cache,
                         bot=bot, default_model=default_model, stream_model=stream_model, audio_model=audio_model,
                         rate_limit=rate_limit, burst=burst,
                         token=token or None, allowed_hosts=tuple(dict.fromkeys(hosts)),
                         allowed_origins=tuple(dict.fromkeys((*hosts, *allow_origin))), max_queue=max_queue,
                         max_streams=max_streams, max_streams_per_ip=max_streams_per_ip, idle_timeout=idle_timeout,
                         stream_timeout=stream_timeout, cache_bytes=cache_mb * 1024 * 1024, scale=scale,
                         voice=variant, **extra)
    app = create_app(config)  # with several processes: checks the settings and models once, here
    service = app.state.service
    click.echo(f"vispeech serving on http://{host}:{port}/ (cache {service.cache.path}, "
               f"stream model {service.stream_model}, audio model {service.audio_model or 'none'}"
               f"{f', {processes} processes' if processes > 1 else ''}{', token required' if token else ''})")
    options = {"host": host, "port": port, "log_level": log_level, "ws_max_size": config.max_message_bytes,
               "ws_per_message_deflate": ws_deflate, "timeout_graceful_shutdown": 5}
    if processes == 1:
        uvicorn.run(app, **options)
        return
    import os

    from vispeech.serve.config import CONFIG_VARIABLE

    os.environ[CONFIG_VARIABLE] = config.to_json()
    del app, service
    uvicorn.run("vispeech.serve.app:app_from_environment", factory=True, workers=processes, **options)
