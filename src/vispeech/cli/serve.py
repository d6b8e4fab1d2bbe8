"""``vispeech serve``: the web server (chat page, players, speak / chat / stream APIs)."""

from __future__ import annotations

import dataclasses
import functools
import os
import typing
from pathlib import Path

import click

from vispeech.cli import allow_host_option, main, scale_option
from vispeech.pipeline import DEFAULT_SCALE


class _ServeCommand(click.Command):
    """A command whose options after ``--port`` begin with one for each :class:`~vispeech.serve.ServeConfig`
    field that has an :class:`~vispeech.serve.config.Option`, made when the command runs or shows its
    help (listing the commands imports no server module)."""

    @functools.cached_property
    def config_params(self) -> list[click.Option]:
        from vispeech.serve.config import ServeConfig

        hints = typing.get_type_hints(ServeConfig)
        return [_config_option(f, hints[f.name]) for f in dataclasses.fields(ServeConfig) if "option" in f.metadata]

    def get_params(self, ctx: click.Context) -> list[click.Parameter]:
        params = super().get_params(ctx)
        after_port = next(i for i, param in enumerate(params) if param.name == "port") + 1
        return [*params[:after_port], *self.config_params, *params[after_port:]]


def _config_option(field: dataclasses.Field, hint: typing.Any) -> click.Option:
    """The click option of a :class:`~vispeech.serve.ServeConfig` field: its name, type and default
    from the field, the rest from the field's :class:`~vispeech.serve.config.Option`."""
    option = field.metadata["option"]
    if option.negated:
        return click.Option([option.name, field.name], is_flag=True, flag_value=False, default=True, help=option.help)
    kinds = set(typing.get_args(hint)) - {type(None)} or {hint}
    kind: click.ParamType | type = str
    if option.url:
        kind = str
    elif kinds & {Path, os.PathLike}:
        kind = click.Path(path_type=Path, dir_okay=False)
    elif int in kinds:
        kind = int if option.minimum is None else click.IntRange(min=int(option.minimum))
    elif float in kinds:
        kind = float if option.minimum is None else click.FloatRange(min=option.minimum)
    default = None if field.default is dataclasses.MISSING else field.default
    if default is not None and option.unit != 1:
        default //= option.unit
    return click.Option(
        [option.name, field.name],
        type=kind,
        default=default,
        show_default=default is not None,
        envvar=option.envvar,
        show_envvar=option.envvar is not None,
        help=option.help,
        callback=None if option.unit == 1 else lambda ctx, param, value: value * option.unit,
    )


@main.command(cls=_ServeCommand)
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (0.0.0.0: every interface).")
@click.option("--port", default=8000, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option(
    "--chat-url",
    metavar="URL",
    help="OpenAI-compatible chat model to answer chats instead of the rule bot: its base URL, as OpenAI's "
    "SDKs take it (http://127.0.0.1:11434/v1: Ollama; http://127.0.0.1:8080/v1: llama.cpp; "
    "https://api.openai.com/v1), or the full .../chat/completions URL.",
)
@click.option("--chat-model", metavar="NAME", help="Model the chat service is asked for (llama3.2, gpt-4o-mini, ...).")
@click.option(
    "--chat-key",
    metavar="KEY",
    envvar="VISPEECH_CHAT_KEY",
    show_envvar=True,
    help="API key sent to the chat service as a bearer token (never shown or logged).",
)
@click.option("--chat-system", metavar="TEXT", help="System prompt put before each chat's conversation.")
@click.option(
    "--chat-system-file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="File holding the system prompt (instead of --chat-system).",
)
@click.option(
    "--chat-timeout",
    default=60.0,
    show_default=True,
    type=click.FloatRange(min=1),
    help="Seconds to wait for the chat service to answer, and for each piece of its reply.",
)
@click.option(
    "--reply-languages",
    default="en,sv",
    show_default=True,
    metavar="CODES",
    help="Languages a reply's sentences are told apart among, each spoken in its own (comma-separated "
    "codes of `vispeech languages`; the page's language is always one).",
)
@allow_host_option
@click.option(
    "--allow-origin",
    multiple=True,
    metavar="ORIGIN",
    help="Browser origin (https://app.example.com, or a host name) allowed to use the API and the "
    "stream, beside the server's own and the allowed hosts (repeatable; * for any). Others get 403.",
)
@click.option(
    "--processes",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="Server processes sharing the port and the SQLite cache, each with its models and threads "
    "(limits count per process).",
)
@click.option(
    "--ws-deflate/--no-ws-deflate",
    default=False,
    show_default=True,
    help="Compress WebSocket messages (permessage-deflate): less traffic, more CPU per message.",
)
@click.option(
    "--log-level",
    default="info",
    show_default=True,
    type=click.Choice(["critical", "error", "warning", "info", "debug"]),
    help="Server log level.",
)
@scale_option(DEFAULT_SCALE)
def serve(
    host: str,
    port: int,
    chat_url: str | None,
    chat_model: str | None,
    chat_key: str | None,
    chat_system: str | None,
    chat_system_file: Path | None,
    chat_timeout: float,
    reply_languages: str,
    allow_host: tuple[str, ...],
    allow_origin: tuple[str, ...],
    processes: int,
    ws_deflate: bool,
    log_level: str,
    **settings: typing.Any,
) -> None:
    """Serve the chat page at http://HOST:PORT/, the players and the JSON / WebSocket APIs.

    API documentation is at /docs; docs/serve.md lists the limits. Stop with Ctrl+C.
    """
    import uvicorn

    from vispeech.files import read_text
    from vispeech.guards import hosts_for
    from vispeech.serve import OpenAIChatBot, RuleBot, ServeConfig, create_app
    from vispeech.serve.config import CONFIG_VARIABLE

    if chat_system is not None and chat_system_file is not None:
        raise click.UsageError("give --chat-system or --chat-system-file, not both")
    if chat_system_file is not None:
        chat_system = read_text(chat_system_file, "system prompt file").strip()
    bot = (
        OpenAIChatBot(chat_url, chat_model, key=chat_key, system=chat_system, timeout=chat_timeout)
        if chat_url
        else RuleBot()
    )
    hosts = hosts_for(host, allow_host)
    settings["token"] = settings["token"] or None  # --token "" asks for none
    config = ServeConfig(
        **{name: value for name, value in settings.items() if value is not None},
        bot=bot,
        reply_languages=tuple(code.strip() for code in reply_languages.split(",") if code.strip()),
        allowed_hosts=hosts,
        allowed_origins=tuple(dict.fromkeys((*hosts, *allow_origin))),
    )
    app = create_app(config)  # with several processes: checks the settings and models once, here
    service = app.state.service
    click.echo(
        f"vispeech serving on http://{host}:{port}/ (cache {service.cache.path}, "
        f"stream model {service.stream_model}, audio model {service.audio_model or 'none'}"
        f"{f', {processes} processes' if processes > 1 else ''}{', token required' if config.token else ''})"
    )
    if isinstance(bot, OpenAIChatBot):
        model = bot.model or "the service's default"
        click.echo(f"chat model: {model} at {bot.url}{', with a key' if bot.key else ''}")
    options: dict[str, typing.Any] = {
        "host": host,
        "port": port,
        "log_level": log_level,
        "ws_max_size": config.max_message_bytes,
        "ws_per_message_deflate": ws_deflate,
        "timeout_graceful_shutdown": 5,
    }
    if processes == 1:
        uvicorn.run(app, **options)
        return
    os.environ[CONFIG_VARIABLE] = config.to_json()
    del app, service
    uvicorn.run("vispeech.serve.app:app_from_environment", factory=True, workers=processes, **options)
