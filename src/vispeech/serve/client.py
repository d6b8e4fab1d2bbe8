"""A client of ``/api/stream`` that times what it receives (``vispeech stream``, the load benchmark)."""

from __future__ import annotations

import base64
import json
import time
from dataclasses import dataclass


@dataclass
class StreamTimings:
    """What one streamed text took, in seconds from sending it.

    A frame is late when it arrives after its presentation time, taking playback to start
    when the first audio chunk arrives: frame k is due ``k / fps`` s after that; an audio
    chunk starting ``s`` s in is due ``s`` s after it.
    """

    first_frame: float
    first_audio: float
    total: float
    n_frames: int
    fps: float
    audio_seconds: float
    frames_late: int
    audio_late: int
    n_audio: int
    model: str = ""

    def summary(self) -> str:
        ms = 1000.0
        return "\n".join([
            f"model          {self.model}",
            f"first frame    {self.first_frame * ms:8.1f} ms",
            f"first audio    {self.first_audio * ms:8.1f} ms",
            f"total          {self.total * ms:8.1f} ms  ({self.audio_seconds:.2f} s of audio, "
            f"{self.n_frames} frames at {self.fps:g} fps)",
            f"frames late    {self.frames_late} of {self.n_frames}",
            f"audio late     {self.audio_late} of {self.n_audio} chunks",
        ])


async def time_stream(url: str, text: str, lang: str = "en", model: str | None = None,
                      timeout: float = 60.0) -> StreamTimings:
    """Send ``text`` to the stream at ``url`` (``ws://host:port/api/stream``) and time the answer.

    Raises :class:`RuntimeError` when the server answers with an error or the stream breaks off.
    """
    import asyncio

    import websockets

    frames: list[tuple[float, int, int]] = []
    audio: list[tuple[float, float]] = []  # arrival, start in the audio
    start_message: dict = {}
    samples = 0
    async with websockets.connect(url, max_size=None, open_timeout=timeout, close_timeout=2) as ws:
        sent = time.perf_counter()
        await ws.send(json.dumps({"type": "text", "text": text, "lang": lang, "model": model}))
        async with asyncio.timeout(timeout):
            async for raw in ws:
                now = time.perf_counter() - sent
                message = json.loads(raw)
                kind = message.get("type")
                if kind == "start":
                    start_message = message
                elif kind == "frames":
                    frames.append((now, message["start_frame"], len(message["frames"])))
                elif kind == "audio":
                    audio.append((now, float(message["start"])))
                    samples += len(base64.b64decode(message["pcm16"])) // 2
                elif kind == "end":
                    total = now
                    break
                elif kind == "error":
                    raise RuntimeError(f"server error: {message.get('message')}")
            else:
                raise RuntimeError("the stream closed before its end")
    if not frames or not audio:
        raise RuntimeError("the stream sent no frames or no audio")
    fps = float(start_message.get("fps", 30.0))
    playback = audio[0][0]
    late = sum(
        1 for arrival, first, count in frames for k in range(first, first + count) if arrival > playback + k / fps
    )
    return StreamTimings(
        first_frame=frames[0][0], first_audio=audio[0][0], total=total,
        n_frames=sum(count for _, _, count in frames), fps=fps,
        audio_seconds=samples / float(start_message.get("sample_rate") or 22050),
        frames_late=late, audio_late=sum(1 for arrival, start in audio if arrival > playback + start),
        n_audio=len(audio), model=str(start_message.get("model", "")),
    )
