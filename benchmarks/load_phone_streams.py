"""Latency of phone streams (a TTS engine's or a recogniser's) under many concurrent sessions.

    python benchmarks/load_phone_streams.py [--sessions 50] [--piece 0.2] [--json OUT]

Starts `vispeech serve` on 127.0.0.1 (no rate limit, a temporary cache), then opens
``--sessions`` WebSocket sessions at once on ``/api/stream``, each from a loopback address of its
own (127.32.k.1: the server caps connections per address and per /24). Each sends the phones of a
6-sentence reply (espeak-ng's, computed here once) as a TTS engine would: in pieces of
``--piece`` seconds of speech, each piece sent when the speech before it has played (real time).
For every ``frames`` message, the time since the piece before it was sent is measured; a
piece is late when that exceeds the piece's own length (the frames would not keep up with the
speech). Prints p50 / p95 / max of that latency, the late pieces, and the server's CPU seconds.

Run it on two checkouts to compare a change (``PYTHONPATH=OTHER/src`` for the other).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time

import numpy as np
import websockets
from local_server import running_server

from vispeech.frontends.espeak import synthesize

TEXT = ("Hello, and welcome! I can answer your questions about opening hours, prices and parking. "
        "We open at nine and close at six. Parking is free for the first two hours. "
        "What would you like to know?")


async def session(url: str, pieces: list[list[dict]], piece_seconds: float, start_at: float,
                  ip: str = "127.0.0.1") -> list[float]:
    """Send the pieces in real time from address ``ip``; for each ``frames`` message, the seconds since
    the piece before it was sent (a piece may make no frame ready: its frames come with a later one)."""
    latencies: list[float] = []
    sent = [0.0]
    async with websockets.connect(url, max_size=2**24, local_addr=(ip, 0)) as ws:
        await asyncio.sleep(max(0.0, start_at - time.perf_counter()))

        async def send() -> None:
            began = time.perf_counter()
            for k, piece in enumerate(pieces):
                await asyncio.sleep(max(0.0, began + k * piece_seconds - time.perf_counter()))
                sent[0] = time.perf_counter()
                await ws.send(json.dumps({"type": "phones", "phones": piece, "language": "en", "final": False}))
            await ws.send(json.dumps({"type": "phones", "phones": [], "language": "en", "final": True}))

        async def receive() -> None:
            while True:
                message = json.loads(await ws.recv())
                if message["type"] == "frames" and sent[0]:
                    latencies.append(time.perf_counter() - sent[0])
                elif message["type"] == "error":
                    raise RuntimeError(message["message"])
                elif message["type"] == "end":
                    return

        await asyncio.gather(send(), receive())
    return latencies[:-1]  # the last answers "final": not a piece's


def phone_pieces(piece_seconds: float) -> list[list[dict]]:
    phones = synthesize(TEXT, "en").phones
    pieces: list[list[dict]] = [[]]
    for p in phones:
        if pieces[-1] and p.end > piece_seconds * len(pieces):
            pieces.append([])
        pieces[-1].append({"symbol": p.symbol, "start": p.start, "end": p.end, "stress": p.stress})
    return pieces


async def run(url: str, sessions: int, piece_seconds: float) -> dict:
    pieces = phone_pieces(piece_seconds)
    await session(url, pieces[:5], piece_seconds, time.perf_counter())  # warm-up
    start_at = time.perf_counter() + 2.0
    outcomes = await asyncio.gather(
        *(session(url, pieces, piece_seconds, start_at, f"127.32.{k}.1") for k in range(sessions)),
        return_exceptions=True)
    latencies = [x for o in outcomes if isinstance(o, list) for x in o]
    failures = [repr(o) for o in outcomes if not isinstance(o, list)]
    values = np.array(latencies)
    return {"sessions": sessions, "failed": len(failures), "failures": failures[:3], "pieces": len(values),
            "piece_seconds": piece_seconds, "speech_seconds": pieces[-1][-1]["end"],
            "latency_ms_p50": float(np.percentile(values, 50) * 1000) if len(values) else None,
            "latency_ms_p95": float(np.percentile(values, 95) * 1000) if len(values) else None,
            "latency_ms_max": float(values.max() * 1000) if len(values) else None,
            "late_pieces": int((values > piece_seconds).sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=50)
    parser.add_argument("--piece", type=float, default=0.2, help="seconds of speech per phones message")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    with running_server("--rate-limit", "0", "--max-streams-per-ip", "200") as server:
        cpu = server.cpu_seconds()
        report = asyncio.run(run(server.stream_url, args.sessions, args.piece))
        report["server_cpu_s"] = None if cpu is None else server.cpu_seconds() - cpu
    print(f"{report['sessions']} phone streams ({report['failed']} failed), {report['speech_seconds']:.1f} s of "
          f"speech each in pieces of {report['piece_seconds']:g} s, {report['pieces']} pieces:")
    print(f"  frames after a piece: p50 {report['latency_ms_p50']:.1f} ms, p95 {report['latency_ms_p95']:.1f} ms, "
          f"max {report['latency_ms_max']:.1f} ms; late pieces {report['late_pieces']}; "
          f"server CPU {report['server_cpu_s']:.1f} s")
    for failure in report["failures"]:
        print(f"  failure: {failure}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(report, out, indent=2)


if __name__ == "__main__":
    main()
