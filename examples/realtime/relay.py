"""Example clients: a realtime voice service's stream relayed to vispeech's ``/api/listen``, one
for each shape of service (docs/serve.md, "Realtime voice services").

    python examples/realtime/relay.py openai|elevenlabs|azure|azure-visemes
                                      [--url ws://127.0.0.1:8000/api/listen] [--out frames.json]

replays a recorded fixture (``fixtures/``, made by ``make_fixtures.py``: no network, no account)
through a running ``vispeech serve`` and prints what came back. Each ``*_messages`` function
turns the service's events, in the order the service sends them, into the messages of
``/api/listen``; a live client feeds it the service's events as they arrive instead of the fixture's:

- :func:`openai_messages` (OpenAI Realtime, Gemini Live: PCM and no timings): the audio alone,
  which the server's audio model animates;
- :func:`elevenlabs_messages` (ElevenLabs with timestamps: PCM and characters with times):
  each chunk's audio, then its ``alignment`` as a ``characters`` message;
- :func:`azure_messages` (Azure Speech: PCM, word boundaries and visemes): the audio, and the
  word boundaries as ``words`` messages (or, with ``timings="visemes"``, the visemes as
  ``visemes`` messages), each forwarded when the service sends it, before or after its audio.

:func:`relay` sends the messages over a WebSocket (the ``websockets`` package) and collects the
frames; the tests run the same functions through the server in-process (tests/test_realtime_listen.py).
On barge-in (the user starts talking) a client stops playing, sends ``{"type": "cancel",
"frame": k}`` (``k``: the frame it shows) and shows the ``cancelled`` message's frames at once
in place of every frame after ``k``.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import soundfile

FIXTURES = Path(__file__).parent / "fixtures"
TICKS = 10_000_000
"""Azure's ticks (100 ns) per second."""
AUDIO_FIELDS = {"openai": "delta", "elevenlabs": "audio_base64", "azure": "audio_data"}
"""Where each service carries its base64 audio in an event."""


def read_fixture(service: str) -> tuple[list[dict], int]:
    """The recorded events of ``service`` (``openai``, ``elevenlabs``, ``azure``) with their audio
    put back as the service sends it (base64 16-bit PCM), and the audio's sample rate."""
    samples, rate = soundfile.read(FIXTURES / "speech.flac", dtype="int16")
    events = []
    for line in (FIXTURES / f"{service}.jsonl").read_text(encoding="utf-8").splitlines():
        event = json.loads(line)
        if "samples" in event:
            a, b = event.pop("samples")
            event[AUDIO_FIELDS[service]] = base64.b64encode(samples[a:b].tobytes()).decode("ascii")
        events.append(event)
    return events, rate


def start(sample_rate: int, timings: str | None = None) -> str:
    return json.dumps({"type": "start", "sample_rate": sample_rate, "timings": timings})


def openai_messages(events: Iterable[dict], sample_rate: int = 24000) -> Iterator[str | bytes]:
    """OpenAI Realtime's ``response.output_audio.delta`` events (PCM16, 24 kHz unless set
    otherwise) as ``/api/listen`` messages: the audio alone."""
    yield start(sample_rate)
    for event in events:
        if event["type"] == "response.output_audio.delta":
            yield base64.b64decode(event["delta"])
        elif event["type"] == "response.output_audio.done":
            yield json.dumps({"type": "stop"})


def elevenlabs_messages(chunks: Iterable[dict], sample_rate: int = 16000) -> Iterator[str | bytes]:
    """ElevenLabs' chunks with timestamps (``audio_base64`` of ``pcm_16000``, ``alignment``) as
    ``/api/listen`` messages: each chunk's audio, then its characters with their times."""
    yield start(sample_rate, "characters")
    for chunk in chunks:
        yield base64.b64decode(chunk["audio_base64"])
        if chunk.get("alignment"):
            yield json.dumps({"type": "characters", **chunk["alignment"]})
    yield json.dumps({"type": "stop"})


def azure_messages(events: Iterable[dict], sample_rate: int = 16000, timings: str = "words") -> Iterator[str | bytes]:
    """Azure Speech's events (``Synthesizing`` audio, ``WordBoundary``, ``VisemeReceived``,
    ``SynthesisCompleted``) as ``/api/listen`` messages, with its ``words`` or its ``visemes``."""
    yield start(sample_rate, timings)
    for event in events:
        kind = event["event"]
        if kind == "Synthesizing":
            yield base64.b64decode(event["audio_data"])
        elif kind == "WordBoundary" and timings == "words":
            begin = event["audio_offset"] / TICKS
            word = {"text": event["text"], "start": begin, "end": begin + event["duration"] / TICKS}
            yield json.dumps({"type": "words", "words": [word]})
        elif kind == "VisemeReceived" and timings == "visemes":
            viseme = {"viseme": event["viseme_id"], "time": event["audio_offset"] / TICKS}
            yield json.dumps({"type": "visemes", "visemes": [viseme]})
        elif kind == "SynthesisCompleted":
            yield json.dumps({"type": "stop"})


def messages_for(service: str) -> Iterator[str | bytes]:
    """The ``/api/listen`` messages of ``service``'s fixture (``azure-visemes``: Azure's visemes)."""
    events, rate = read_fixture(service.split("-")[0])
    if service == "openai":
        return openai_messages(events, rate)
    if service == "elevenlabs":
        return elevenlabs_messages(events, rate)
    return azure_messages(events, rate, "visemes" if service == "azure-visemes" else "words")


def frames_of(answers: list[dict]) -> np.ndarray:
    """The frames of one stream's answers, in order (rows over the start message's channels)."""
    rows: list[list[float]] = []
    for answer in answers:
        if answer["type"] in ("frames", "cancelled"):
            assert answer["start_frame"] == len(rows), "frames arrive in order"
            rows += answer["frames"]
    return np.array(rows)


async def relay(url: str, messages: Iterable[str | bytes]) -> list[dict]:
    """Send ``messages`` to ``/api/listen`` at ``url`` while receiving; the server's answers up to
    ``end`` (or ``cancelled``). Raises :class:`RuntimeError` on an ``error``."""
    import websockets

    answers: list[dict] = []
    async with websockets.connect(url, max_size=2**24) as ws:

        async def send() -> None:
            for message in messages:
                await ws.send(message)

        sender = asyncio.create_task(send())  # a live client forwards as the service sends
        try:
            while not answers or answers[-1]["type"] not in ("end", "cancelled"):
                answers.append(json.loads(await ws.recv()))
                if answers[-1]["type"] == "error":
                    raise RuntimeError(answers[-1]["message"])
        finally:
            sender.cancel()
    return answers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("service", choices=["openai", "elevenlabs", "azure", "azure-visemes"])
    parser.add_argument("--url", default="ws://127.0.0.1:8000/api/listen")
    parser.add_argument("--out", type=Path, help="write the frames as JSON (channels, fps, frames)")
    args = parser.parse_args()
    answers = asyncio.run(relay(args.url, messages_for(args.service)))
    begin, end = answers[0], answers[-1]
    frames = frames_of(answers)
    print(f"{args.service}: {len(frames)} frames at {begin['fps']:g} fps from {begin['model']}, "
          f"{end['duration']:.2f} s of audio")
    if args.out:
        args.out.write_text(json.dumps({"channels": begin["channels"], "fps": begin["fps"],
                                        "frames": frames.tolist()}))


if __name__ == "__main__":
    main()
