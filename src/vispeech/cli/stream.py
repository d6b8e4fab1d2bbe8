"""``vispeech stream``: speak a text through a running server's stream and time it."""

from __future__ import annotations

import click

from vispeech.cli import lang_option, main
from vispeech.errors import VispeechError


@main.command()
@click.argument("text")
@click.option("--url", default="ws://127.0.0.1:8000/api/stream", show_default=True, help="The server's stream URL.")
@lang_option("Language of the text: sv or en.")
@click.option("--model", "-m", default=None, help="Model name [default: the server's stream model].")
@click.option("--timeout", default=60.0, show_default=True, type=float, help="Seconds to wait for the whole stream.")
def stream(text: str, url: str, lang: str, model: str | None, timeout: float) -> None:
    """Stream TEXT from a `vispeech serve` server and print latency figures.

    Time to the first animation frame and to the first audio chunk, the total time, and
    the frames that arrived after their presentation time (playback taken to start when
    the first audio chunk arrives).
    """
    import asyncio

    from websockets.exceptions import WebSocketException

    from vispeech.serve.client import time_stream

    try:
        timings = asyncio.run(time_stream(url, text, lang, model, timeout))
    except (OSError, RuntimeError, TimeoutError, WebSocketException) as exc:
        raise VispeechError(f"streaming from {url} failed: {exc}") from None
    click.echo(timings.summary())
