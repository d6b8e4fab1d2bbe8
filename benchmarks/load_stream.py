"""Latency of the /api/stream WebSocket, alone and under 50 concurrent sessions.

    python benchmarks/load_stream.py [--sessions 50] [--runs 5] [--language en] [--text TEXT] [--json OUT] [--processes N]

Starts `vispeech serve` on 127.0.0.1 on a free port in a subprocess (no rate limit, no
per-address or per-network stream cap since every session comes from 127.0.0.1, a temporary cache), then:

1. one session at a time, ``--runs`` times (after one warm-up): time from sending the text
   to the first animation frame, to the first audio chunk, and to the end;
2. ``--sessions`` sessions at once, each sending the text as soon as it is connected:
   p50 / p95 of the same times, and the frames delivered late. A frame is late when it
   arrives after its presentation time, playback taken to start when the session's first
   audio chunk arrives (frame k is due k / fps s later).

The clients run in this process (asyncio), on the same machine as the server. Everything
stops by itself within ``--deadline`` seconds.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time

import numpy as np
from local_server import LocalServer, running_server

from vispeech.serve.client import StreamTimings, time_stream

TEXTS = {
    "en": "Hello, and welcome! I can answer your questions about opening hours, prices and parking. "
          "What would you like to know?",
    "sv": "Hej och välkommen! Jag kan svara på frågor om öppettider, priser och parkering. "
          "Vad vill du veta?",
}


def _ms(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) * 1000.0


def report_single(runs: list[StreamTimings]) -> dict:
    return {
        "runs": len(runs),
        "first_frame_ms_median": statistics.median(r.first_frame for r in runs) * 1000,
        "first_audio_ms_median": statistics.median(r.first_audio for r in runs) * 1000,
        "total_ms_median": statistics.median(r.total for r in runs) * 1000,
        "audio_seconds": runs[0].audio_seconds,
        "frames": runs[0].n_frames,
        "frames_late": sum(r.frames_late for r in runs),
        "model": runs[0].model,
    }


def report_concurrent(results: list[StreamTimings], failures: list[str], wall: float) -> dict:
    first_frame = [r.first_frame for r in results]
    first_audio = [r.first_audio for r in results]
    total = [r.total for r in results]
    return {
        "sessions": len(results) + len(failures),
        "failed": len(failures),
        "failures": failures[:5],
        "wall_s": wall,
        "first_frame_ms_p50": _ms(first_frame, 50), "first_frame_ms_p95": _ms(first_frame, 95),
        "first_frame_ms_max": _ms(first_frame, 100),
        "first_audio_ms_p50": _ms(first_audio, 50), "first_audio_ms_p95": _ms(first_audio, 95),
        "total_ms_p50": _ms(total, 50), "total_ms_p95": _ms(total, 95),
        "frames": sum(r.n_frames for r in results),
        "frames_late": sum(r.frames_late for r in results),
        "sessions_with_late_frames": sum(1 for r in results if r.frames_late),
        "audio_chunks": sum(r.n_audio for r in results),
        "audio_chunks_late": sum(r.audio_late for r in results),
        "late_warnings": sum(r.warnings for r in results),
        "sessions_warned": sum(1 for r in results if r.warnings),
    }


async def run(server: LocalServer, text: str, lang: str, sessions: int, runs: int) -> dict:
    url = server.stream_url
    await time_stream(url, text, lang)  # warm-up
    single = [await time_stream(url, text, lang) for _ in range(runs)]
    started, cpu = time.perf_counter(), server.cpu_seconds()
    outcomes = await asyncio.gather(*(time_stream(url, text, lang) for _ in range(sessions)), return_exceptions=True)
    wall = time.perf_counter() - started
    server_cpu = None if cpu is None else server.cpu_seconds() - cpu
    results = [o for o in outcomes if isinstance(o, StreamTimings)]
    failures = [repr(o) for o in outcomes if not isinstance(o, StreamTimings)]
    if not results:
        raise RuntimeError(f"every concurrent session failed, e.g. {failures[0]}")
    return {"text": text, "language": lang, "single": report_single(single),
            "concurrent": {**report_concurrent(results, failures, wall), "server_cpu_s": server_cpu}}


def print_report(report: dict) -> None:
    s, c = report["single"], report["concurrent"]
    print(f"text: {report['text']!r} ({s['audio_seconds']:.2f} s of audio, {s['frames']} frames), model {s['model']}")
    print(f"single session (median of {s['runs']}): first frame {s['first_frame_ms_median']:.1f} ms, "
          f"first audio {s['first_audio_ms_median']:.1f} ms, total {s['total_ms_median']:.1f} ms, "
          f"frames late {s['frames_late']}")
    cpu = "" if c["server_cpu_s"] is None else f", server CPU {c['server_cpu_s']:.2f} s"
    print(f"{c['sessions']} concurrent sessions ({c['failed']} failed, {c['wall_s']:.2f} s wall{cpu}):")
    print(f"  first frame  p50 {c['first_frame_ms_p50']:8.1f} ms   p95 {c['first_frame_ms_p95']:8.1f} ms   "
          f"max {c['first_frame_ms_max']:8.1f} ms")
    print(f"  first audio  p50 {c['first_audio_ms_p50']:8.1f} ms   p95 {c['first_audio_ms_p95']:8.1f} ms")
    print(f"  total        p50 {c['total_ms_p50']:8.1f} ms   p95 {c['total_ms_p95']:8.1f} ms")
    print(f"  frames late  {c['frames_late']} of {c['frames']} ({c['sessions_with_late_frames']} sessions); "
          f"audio chunks late {c['audio_chunks_late']} of {c['audio_chunks']}")
    print(f"  late warnings {c['late_warnings']} ({c['sessions_warned']} sessions told they were late)")
    for failure in c["failures"]:
        print(f"  failure: {failure}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=50, help="concurrent sessions (1..100)")
    parser.add_argument("--runs", type=int, default=5, help="single-session runs (1..50)")
    parser.add_argument("--language", default="en", choices=sorted(TEXTS))
    parser.add_argument("--text", help="text to stream (default: a three-sentence chat reply)")
    parser.add_argument("--deadline", type=float, default=300.0, help="seconds before everything stops")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--processes", type=int, default=1, help="server processes (vispeech serve --processes)")
    parser.add_argument("--settle", type=float, default=10.0,
                        help="seconds to wait, with several processes, for every one to be ready")
    args = parser.parse_args()
    sessions, runs = min(max(args.sessions, 1), 100), min(max(args.runs, 1), 50)
    text = args.text or TEXTS[args.language]

    async def bounded(server: LocalServer) -> dict:
        if args.processes > 1:  # the first process to answer may not be the last to have loaded its models
            await asyncio.sleep(args.settle)
        async with asyncio.timeout(args.deadline):
            return await run(server, text, args.language, sessions, runs)

    # every session comes from 127.0.0.1: lift the per-address and per-/24 caps, as distinct clients would not meet them
    with running_server("--rate-limit", "0", "--max-streams-per-ip", "200", "--max-streams-per-network", "200",
                        "--processes", str(args.processes)) as server:
        report = asyncio.run(bounded(server))
    print_report(report)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(report, handle, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
