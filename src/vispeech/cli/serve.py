"""``vispeech serve``: the web server (chat page, players, speak / chat / stream APIs)."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import main
from vispeech.pipeline import DEFAULT_MODEL


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (0.0.0.0: every interface).")
@click.option("--port", default=8000, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option("--avatar", type=click.Path(path_type=Path, dir_okay=False),
              help="glTF binary head served as /avatar.glb.")
@click.option("--avatar-credit",
              help='Credit line shown under the head, e.g. "3D head: ICT-FaceKit (USC ICT), MIT licence".')
@click.option("--cache", type=click.Path(path_type=Path, dir_okay=False),
              help="SQLite file of the utterance cache [default: serve.sqlite3 in ~/.cache/vispeech].")
@click.option("--model", "default_model", default=DEFAULT_MODEL, show_default=True,
              help="Default model of /api/speak and /api/chat.")
@click.option("--stream-model", help="Model name or saved model folder for /api/stream "
              "[default: the shipped grid-tdnn-lowlatency].")
@click.option("--rate-limit", default=2.0, show_default=True, type=click.FloatRange(min=0),
              help="Requests a second per client IP for speak, chat and stream texts (0: no limit).")
@click.option("--burst", default=20, show_default=True, type=click.IntRange(min=1),
              help="Requests a client may make at once.")
@click.option("--chat-url",
              help="External chat service to relay /api/chat messages to (POST JSON) instead of the rule bot.")
@click.option("--chat-reply-field", default="reply", show_default=True,
              help="Where the chat service's JSON answer holds the reply (dotted path: choices.0.message.content).")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["critical", "error", "warning", "info", "debug"]), help="Server log level.")
def serve(host: str, port: int, avatar: Path | None, avatar_credit: str | None, cache: Path | None,
          default_model: str, stream_model: str | None, rate_limit: float, burst: int, chat_url: str | None,
          chat_reply_field: str, log_level: str) -> None:
    """Serve the chat page at http://HOST:PORT/, the players and the JSON / WebSocket APIs.

    API documentation is at /docs. Stop with Ctrl+C.
    """
    import uvicorn

    from vispeech.serve import HTTPChatBot, RuleBot, ServeConfig, create_app

    bot = HTTPChatBot(chat_url, reply_field=chat_reply_field) if chat_url else RuleBot()
    config = ServeConfig(avatar=avatar, avatar_credit=avatar_credit, cache=cache, bot=bot, default_model=default_model,
                         stream_model=stream_model, rate_limit=rate_limit, burst=burst)
    app = create_app(config)
    service = app.state.service
    click.echo(f"vispeech serving on http://{host}:{port}/ (cache {service.cache.path}, "
               f"stream model {service.stream_model})")
    uvicorn.run(app, host=host, port=port, log_level=log_level, ws_max_size=config.max_message_bytes,
                timeout_graceful_shutdown=5)
