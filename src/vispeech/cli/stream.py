"""``vispeech stream``: speak a text through a running server's stream, or replay an audio file as
live audio to it, and time what comes back."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import language_option, main
from vispeech.errors import VispeechError
from vispeech.limits import MAX_FPS, MIN_FPS

SERVER = "ws://127.0.0.1:8000"


def websocket_url(url: str, route: str) -> str:
    """``url`` as the WebSocket URL of the server's ``/api/<route>``: ``http(s)://`` becomes
    ``ws(s)://``, and a bare server address gets the route."""
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    scheme = {"http": "ws", "https": "wss"}.get(parts.scheme, parts.scheme)
    if scheme not in ("ws", "wss") or not parts.netloc:
        raise click.BadParameter(f"{url!r} is no ws://, wss://, http:// or https:// URL", param_hint="--url")
    path = parts.path if parts.path.strip("/") else f"/api/{route}"
    return parts._replace(scheme=scheme, path=path).geturl()


@main.command()
@click.argument("text", required=False)
@click.option(
    "--audio",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Replay this audio file (WAV, FLAC, MP3, OGG) as live audio to the server's /api/listen.",
)
@click.option(
    "--realtime/--fast",
    default=True,
    show_default=True,
    help="With --audio: send the audio in real time, as a microphone would, or as fast as the server takes it.",
)
@click.option(
    "--chunk-ms",
    default=20,
    show_default=True,
    type=click.IntRange(1, 1000),
    help="With --audio: milliseconds of audio in a chunk.",
)
@click.option(
    "--fps", type=click.FloatRange(MIN_FPS, MAX_FPS), help="With --audio: frame rate [default: the server's]."
)
@click.option(
    "--out",
    "-o",
    type=click.Path(path_type=Path, dir_okay=False),
    help="With --audio: write the frames to this file (format from the extension: .json, .csv, ...).",
)
@click.option(
    "--url",
    help=f"The server's WebSocket URL, or its http:// address [default: {SERVER}/api/stream; with --audio "
    f"{SERVER}/api/listen].",
)
@language_option("Language of the text: sv, en or any other `vispeech languages` lists.")
@click.option("--model", "-m", default=None, help="Model name [default: the server's stream or audio model].")
@click.option(
    "--timeout",
    default=60.0,
    show_default=True,
    type=float,
    help="Seconds to wait for the whole stream (with --audio --realtime: beyond the audio's length).",
)
def stream(
    text: str | None,
    audio: Path | None,
    realtime: bool,
    chunk_ms: int,
    fps: float | None,
    out: Path | None,
    url: str | None,
    language: str,
    model: str | None,
    timeout: float,
) -> None:
    """Stream TEXT from a `vispeech serve` server, or replay an --audio file to it, and print latency figures.

    TEXT: time to the first animation frame and to the first audio chunk, the total time,
    and the frames that arrived after their presentation time (playback taken to start when
    the first audio chunk arrives).

    --audio: the file goes in chunks of 16-bit PCM at its own sample rate; printed are the
    frames received and each frame's delay, from sending the audio at the frame's time to
    receiving the frame (p50, p95, max); --out writes the frames.
    """
    import asyncio

    from websockets.exceptions import WebSocketException

    if (text is None) == (audio is None):
        raise click.UsageError("give a TEXT or an --audio file (not both)")
    if audio is None and (out is not None or fps is not None):
        raise click.UsageError("--out and --fps go with --audio")
    url = websocket_url(url or SERVER, "stream" if audio is None else "listen")
    try:
        if audio is None:
            from vispeech.serve.client import time_stream

            assert text is not None  # TEXT or --audio, checked above
            click.echo(asyncio.run(time_stream(url, text, language, model, timeout)).summary())
            return
        from vispeech.frontends.audio import AudioClip
        from vispeech.serve.client import stream_audio

        clip = AudioClip.read(audio)
        result = asyncio.run(
            stream_audio(
                url,
                clip.samples,
                clip.sample_rate,
                fps=fps,
                model=model,
                chunk_seconds=chunk_ms / 1000,
                realtime=realtime,
                timeout=timeout,
            )
        )
    except (OSError, RuntimeError, TimeoutError, WebSocketException) as exc:
        raise VispeechError(f"streaming from {url} failed: {exc}") from None
    if out is not None:
        from vispeech.motion.formats.registry import write_track

        write_track(result.track(), out)
    click.echo(result.summary())
