"""Clients of ``/api/stream`` and ``/api/listen`` that time what they receive (``vispeech stream``,
the load benchmarks)."""

from __future__ import annotations

import base64
import json
import time
from dataclasses import dataclass, field

import numpy as np

from vispeech.frontends.audio import to_pcm16
from vispeech.motion.track import Track


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
    warnings: int = 0
    """``late`` warnings the server sent (clauses it knew to be late)."""

    def summary(self) -> str:
        ms = 1000.0
        return "\n".join(
            [
                f"model          {self.model}",
                f"first frame    {self.first_frame * ms:8.1f} ms",
                f"first audio    {self.first_audio * ms:8.1f} ms",
                f"total          {self.total * ms:8.1f} ms  ({self.audio_seconds:.2f} s of audio, "
                f"{self.n_frames} frames at {self.fps:g} fps)",
                f"frames late    {self.frames_late} of {self.n_frames}",
                f"audio late     {self.audio_late} of {self.n_audio} chunks",
                f"late warnings  {self.warnings}",
            ]
        )


async def time_stream(
    url: str, text: str, language: str = "en", model: str | None = None, timeout: float = 60.0
) -> StreamTimings:
    """Send ``text`` to the stream at ``url`` (``ws://host:port/api/stream``) and time the answer.

    Raises :class:`RuntimeError` when the server answers with an error or the stream breaks off.
    """
    import asyncio

    import websockets

    frames: list[tuple[float, int, int]] = []
    audio: list[tuple[float, float]] = []  # arrival, start in the audio
    start_message: dict = {}
    samples = warnings = 0
    async with websockets.connect(url, max_size=None, open_timeout=timeout, close_timeout=2) as ws:
        sent = time.perf_counter()
        await ws.send(json.dumps({"type": "text", "text": text, "language": language, "model": model}))
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
                elif kind == "warning":
                    warnings += 1
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
        first_frame=frames[0][0],
        first_audio=audio[0][0],
        total=total,
        n_frames=sum(count for _, _, count in frames),
        fps=fps,
        audio_seconds=samples / float(start_message.get("sample_rate") or 22050),
        frames_late=late,
        audio_late=sum(1 for arrival, start in audio if arrival > playback + start),
        n_audio=len(audio),
        model=str(start_message.get("model", "")),
        warnings=warnings,
    )


@dataclass
class ListenResult:
    """What one live audio stream gave: the server's start message, the frames and their delays.

    ``delays[k]`` is the wall-clock time (seconds) from sending the audio chunk that holds the
    sample at frame k's time (``k / fps``) until frame k arrived: the stream's look-ahead, the
    features, inference and transport.
    """

    start: dict
    frames: np.ndarray
    delays: np.ndarray
    audio_seconds: float
    chunks: int
    chunk_seconds: float
    realtime: bool
    total: float
    """Seconds from the first chunk sent to the end message."""
    warnings: list[str] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return float(self.start["fps"])

    def track(self) -> Track:
        """The frames as a track over the start message's channels."""
        return Track(self.frames, tuple(self.start["channels"]), self.fps)

    def summary(self) -> str:
        ms = 1000.0
        pace = "in real time" if self.realtime else "as fast as taken"
        lines = [
            f"model          {self.start.get('model', '')}",
            f"audio          {self.audio_seconds:.2f} s at {self.start.get('sample_rate')} Hz, {self.chunks} chunks "
            f"of {self.chunk_seconds * ms:.0f} ms sent {pace}",
            f"frames         {len(self.frames)} at {self.fps:g} fps (the stream waits "
            f"{float(self.start.get('delay') or 0) * ms:.0f} ms of audio ahead)",
        ]
        if len(self.delays):
            p50, p95 = np.percentile(self.delays, [50, 95]) * ms
            lines.append(
                f"frame delay    p50 {p50:.1f} ms, p95 {p95:.1f} ms, max {self.delays.max() * ms:.1f} ms "
                "(audio sent to frame received)"
            )
        lines.append(f"total          {self.total * ms:.1f} ms")
        lines += [f"warning        {message}" for message in self.warnings]
        return "\n".join(lines)


async def stream_audio(
    url: str,
    samples: np.ndarray,
    sample_rate: int,
    *,
    fps: float | None = None,
    model: str | None = None,
    chunk_seconds: float = 0.02,
    realtime: bool = True,
    timeout: float = 60.0,
) -> ListenResult:
    """Send ``samples`` (mono floats in [-1, 1] or 16-bit integers at ``sample_rate`` Hz) to
    ``url`` (``ws://host:port/api/listen``) as live audio in chunks of ``chunk_seconds``, paced
    in real time when ``realtime`` (else as fast as the server takes them), and time the frames.

    ``timeout`` is seconds to wait beyond the audio's own length (when paced). Raises
    :class:`RuntimeError` when the server answers with an error or the stream breaks off.
    """
    import asyncio

    import websockets

    pcm = samples if np.issubdtype(np.asarray(samples).dtype, np.integer) else to_pcm16(samples)
    pcm = np.asarray(pcm, dtype="<i2")
    step = max(1, round(chunk_seconds * sample_rate))
    sent: list[tuple[float, int]] = []  # (time the chunk was sent, its end sample)
    seconds = len(pcm) / sample_rate
    async with websockets.connect(url, max_size=None, open_timeout=timeout, close_timeout=2) as ws:
        await ws.send(
            json.dumps({"type": "start", "sample_rate": sample_rate, "encoding": "pcm16", "fps": fps, "model": model})
        )
        async with asyncio.timeout(timeout):
            start = json.loads(await ws.recv())
        if start.get("type") != "start":
            raise RuntimeError(f"server error: {start.get('message', start)}")
        sender = asyncio.create_task(_send_chunks(ws, pcm, step, chunk_seconds, realtime, sent))
        try:
            async with asyncio.timeout(timeout + (seconds if realtime else 0.0)):
                arrivals, warnings, total = await _receive_frames(ws, sent)
            await sender
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)
    frames = np.array([row for _, _, rows in arrivals for row in rows], dtype=float)
    return ListenResult(
        start=start,
        frames=frames.reshape(-1, len(start["channels"])),
        delays=_frame_delays(arrivals, sent, float(start["fps"]), sample_rate, len(pcm)),
        audio_seconds=seconds,
        chunks=len(sent),
        chunk_seconds=step / sample_rate,
        realtime=realtime,
        total=total,
        warnings=warnings,
    )


async def _send_chunks(
    ws, pcm: np.ndarray, step: int, chunk_seconds: float, realtime: bool, sent: list[tuple[float, int]]
) -> None:
    """Send ``pcm`` in chunks of ``step`` samples, then the stop message, noting each chunk in ``sent``."""
    import asyncio

    began = time.perf_counter()
    for i, a in enumerate(range(0, len(pcm), step)):
        if realtime:
            await asyncio.sleep(max(0.0, began + i * chunk_seconds - time.perf_counter()))
        sent.append((time.perf_counter(), min(a + step, len(pcm))))
        await ws.send(pcm[a : a + step].tobytes())
    await ws.send(json.dumps({"type": "stop"}))


async def _receive_frames(ws, sent: list[tuple[float, int]]) -> tuple[list[tuple[float, int, list]], list[str], float]:
    """Read the stream to its end: the frame messages (arrival, first frame, rows), the warnings,
    and the seconds from the first chunk sent to the end message."""
    arrivals: list[tuple[float, int, list]] = []
    warnings: list[str] = []
    async for raw in ws:
        now = time.perf_counter()
        message = json.loads(raw)
        kind = message.get("type")
        if kind == "frames":
            arrivals.append((now, message["start_frame"], message["frames"]))
        elif kind == "warning":
            warnings.append(message["message"])
        elif kind == "end":
            return arrivals, warnings, (now - sent[0][0] if sent else 0.0)
        elif kind == "error":
            raise RuntimeError(f"server error: {message.get('message')}")
    raise RuntimeError("the stream closed before its end")


def _frame_delays(
    arrivals: list[tuple[float, int, list]], sent: list[tuple[float, int]], fps: float, sample_rate: int, n_samples: int
) -> np.ndarray:
    """Each frame's delay: from sending the chunk that holds the sample at its time to its arrival."""
    when, ends = np.array(sent).reshape(-1, 2).T
    delays = []
    for arrival, first, rows in arrivals:
        for k in range(first, first + len(rows)):
            sample = min(int(k / fps * sample_rate), n_samples - 1)
            delays.append(arrival - when[min(int(np.searchsorted(ends, sample, side="right")), len(when) - 1)])
    return np.array(delays)
