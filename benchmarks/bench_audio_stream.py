"""End-to-end delay of live audio: the model's AudioStream in-process, /api/listen alone and under
concurrent sessions.

    python benchmarks/bench_audio_stream.py [--model NAME|FOLDER | --tiny] [--look-ahead 8]
        [--sessions 10] [--clips 3] [--chunk-ms 20] [--rate 16000] [--workers N] [--processes N]
        [--grid ../shared/data/grid_s1] [--json OUT]

The audio is ``--clips`` GRID speaker-1 utterances back to back (3 s each), sent in chunks of
``--chunk-ms`` of 16-bit PCM at ``--rate`` Hz (resampled from GRID's 16 kHz when another),
paced in real time as a microphone would deliver them. A frame's delay is the wall-clock time
from sending the chunk that holds the audio sample at the frame's time (``k / fps``) until
the frame arrived: the model's look-ahead, the features, inference and transport.

1. In-process, no server: the model's :class:`~vispeech.models.networks.audio_stream.AudioStream`
   alone, pushed the 16 kHz chunks in real time (delay = look-ahead + features + inference),
   and the compute time of a push.
2. ``vispeech serve`` in a subprocess on a free loopback port (no rate limit, the per-address
   and per-network stream caps lifted; ``--processes`` server processes): one session, then
   ``--sessions`` at once, all clients in this process.

p50 and p95 are over all frames of all sessions; the server's CPU time and the clients' (this
process's) are reported beside them. ``--model`` is an audio model name or saved
folder (default: the shipped ``grid-audio-cnn``); ``--tiny`` trains the stand-in the tests use
(``audio-cnn``, one epoch, 16 channels a layer, 10 GRID utterances; ``--look-ahead`` frames at
50 fps) into a temporary folder first.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from local_server import running_server

from vispeech.frontends.audio import AudioClip, to_pcm16
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL
from vispeech.serve.client import ListenResult, stream_audio

GRID = Path(__file__).resolve().parents[2] / "shared" / "data" / "grid_s1"


def train_tiny(grid: Path, folder: Path, look_ahead: int) -> Path:
    """The tests' tiny audio-cnn (tests/conftest.py ``tiny_audio_model``), with ``look_ahead`` frames."""
    from vispeech.corpus import align_corpus, read_grid
    from vispeech.models.fitting import Splits
    from vispeech.models.registry import create_model

    root = folder / "grid"
    (root / "utterances").mkdir(parents=True)
    texts = dict(line.split("\t") for line in (grid / "sentences.tsv").read_text().splitlines()[1:])
    ids = sorted(path.stem for path in (grid / "utterances").glob("*.flac"))[:10]
    for uid in ids:
        for ext in ("flac", "align", "csv"):
            shutil.copy(grid / "utterances" / f"{uid}.{ext}", root / "utterances" / f"{uid}.{ext}")
    (root / "sentences.tsv").write_text("id\ttext\n" + "".join(f"{uid}\t{texts[uid]}\n" for uid in ids))
    utterances = list(align_corpus(read_grid(root, cache=root / "cache"), progress=False))
    model = create_model("audio-cnn", epochs=1, channels=[16, 16, 16], pitch_copies=0, look_ahead=look_ahead)
    model.fit(Splits(utterances[:8], utterances[8:]), progress=False)
    return model.save(folder / f"tiny-audio-cnn-ahead{look_ahead}")


def grid_audio(grid: Path, clips: int) -> np.ndarray:
    """``clips`` GRID utterances (the last ones, unseen by the tiny model) back to back, 16 kHz floats."""
    paths = sorted((grid / "utterances").glob("*.flac"))[-clips:]
    return np.concatenate([AudioClip.read(path).resampled(16000).samples for path in paths])


def percentiles(delays: np.ndarray) -> dict:
    return {"frames": int(len(delays)), "p50_ms": float(np.percentile(delays, 50) * 1000),
            "p95_ms": float(np.percentile(delays, 95) * 1000), "max_ms": float(delays.max() * 1000)}


def in_process(model, samples: np.ndarray, fps: float, chunk_seconds: float) -> dict:
    """The model's AudioStream alone, fed 16 kHz chunks in real time: each frame's delay and a push's cost."""
    warm_up = model.stream(None, fps)  # the first push imports and compiles the feature code
    warm_up.push(samples[:16000])
    warm_up.finish()
    stream = model.stream(None, fps)
    step = round(chunk_seconds * 16000)
    sent, delays, costs = [], [], []
    began = time.perf_counter()
    for i, a in enumerate(range(0, len(samples), step)):
        time.sleep(max(0.0, began + i * chunk_seconds - time.perf_counter()))
        sent.append((time.perf_counter(), min(a + step, len(samples))))
        first, rows = stream.push(samples[a:a + step])
        done = time.perf_counter()
        costs.append(done - sent[-1][0])
        ends = np.array([end for _, end in sent])
        for k in range(first, first + len(rows)):
            chunk = min(int(np.searchsorted(ends, int(k / fps * 16000), side="right")), len(sent) - 1)
            delays.append(done - sent[chunk][0])
    stream.finish()
    p50, p95 = np.percentile(costs, [50, 95]) * 1000
    return {**percentiles(np.array(delays)), "delay_s": stream.delay, "push_ms_p50": float(p50), "push_ms_p95": float(p95)}


def own_cpu_seconds() -> float:
    """CPU seconds this process (the benchmark's clients) has used."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def summarise(results: list, wall: float, cpu: float | None, client_cpu: float) -> dict:
    done = [r for r in results if isinstance(r, ListenResult)]
    failures = [repr(r) for r in results if not isinstance(r, ListenResult)]
    if not done:
        raise RuntimeError(f"every session failed, e.g. {failures[0]}")
    return {**percentiles(np.concatenate([r.delays for r in done])), "sessions": len(results),
            "failed": len(failures), "failures": failures[:3], "warnings": sum(len(r.warnings) for r in done),
            "warning_examples": [w for r in done for w in r.warnings][:3], "wall_s": wall, "server_cpu_s": cpu,
            "client_cpu_s": client_cpu,
            "delay_s": float(done[0].start["delay"]), "model": done[0].start["model"]}


async def served(url: str, server, pcm: np.ndarray, rate: int, sessions: int, chunk_seconds: float) -> dict:
    def one():
        return stream_audio(url, pcm, rate, chunk_seconds=chunk_seconds, realtime=True, timeout=60.0)

    await stream_audio(url, pcm[: rate], rate, chunk_seconds=chunk_seconds, realtime=False)  # warm-up
    report = {}
    for label, count in (("single", 1), ("concurrent", sessions)):
        started, cpu, client = time.perf_counter(), server.cpu_seconds(), own_cpu_seconds()
        results = await asyncio.gather(*(one() for _ in range(count)), return_exceptions=True)
        used = None if cpu is None else server.cpu_seconds() - cpu
        report[label] = summarise(results, time.perf_counter() - started, used, own_cpu_seconds() - client)
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default=DEFAULT_AUDIO_STREAM_MODEL, help="audio model name or saved folder")
    parser.add_argument("--tiny", action="store_true", help="train the tests' tiny audio model and use it")
    parser.add_argument("--look-ahead", type=int, default=8, help="the tiny model's look-ahead (frames at 50 fps)")
    parser.add_argument("--sessions", type=int, default=10, help="concurrent sessions (1..100)")
    parser.add_argument("--clips", type=int, default=3, help="GRID utterances a session streams (1..20)")
    parser.add_argument("--chunk-ms", type=int, default=20, help="milliseconds of audio a chunk")
    parser.add_argument("--rate", type=int, default=16000, help="sample rate the client sends (Hz)")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate of the in-process stream")
    parser.add_argument("--workers", type=int, help="the server's worker threads [default: its own]")
    parser.add_argument("--processes", type=int, default=1, help="server processes (vispeech serve --processes)")
    parser.add_argument("--grid", type=Path, default=GRID, help="GRID speaker-1 folder")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    sessions, clips, chunk = min(max(args.sessions, 1), 100), min(max(args.clips, 1), 20), args.chunk_ms / 1000
    with tempfile.TemporaryDirectory(prefix="vispeech-bench-audio-") as tmp:
        folder = str(train_tiny(args.grid, Path(tmp), args.look_ahead)) if args.tiny else args.model
        model = load_model(folder)
        samples = grid_audio(args.grid, clips)
        report = {"model": folder if not args.tiny else f"tiny audio-cnn (look_ahead {args.look_ahead})",
                  "audio_s": len(samples) / 16000, "chunk_ms": args.chunk_ms, "rate": args.rate,
                  "event_loop": "uvloop" if importlib.util.find_spec("uvloop") else "asyncio",
                  "in_process": in_process(model, samples, args.fps, chunk)}
        sent = samples if args.rate == 16000 else AudioClip.from_array(samples, 16000).resampled(args.rate).samples
        pcm = to_pcm16(sent)
        options = ["--rate-limit", "0", "--max-streams-per-ip", "200", "--max-streams-per-network", "200",
                   "--audio-model", folder]
        if args.workers:
            options += ["--workers", str(args.workers)]
        if args.processes > 1:
            options += ["--processes", str(args.processes)]
        with running_server(*options) as server:
            url = server.url.replace("http://", "ws://") + "/api/listen"
            report.update(asyncio.run(served(url, server, pcm, args.rate, sessions, chunk)))
    print_report(report)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2), encoding="utf-8")
    return 0


def print_report(report: dict) -> None:
    print(f"model: {report['model']}; {report['audio_s']:.1f} s of GRID audio a session, "
          f"{report['chunk_ms']} ms chunks at {report['rate']} Hz, paced in real time; "
          f"the server's event loop: {report['event_loop']} (uvicorn takes uvloop where it is installed)")
    p = report["in_process"]
    print(f"in-process AudioStream (delay {p['delay_s'] * 1000:.0f} ms): frame delay p50 {p['p50_ms']:.1f} ms, "
          f"p95 {p['p95_ms']:.1f} ms, max {p['max_ms']:.1f} ms; a push {p['push_ms_p50']:.2f} ms "
          f"(p95 {p['push_ms_p95']:.2f} ms)")
    for label in ("single", "concurrent"):
        r = report[label]
        cpu = "" if r["server_cpu_s"] is None else f", server CPU {r['server_cpu_s']:.1f} s"
        cpu += f", clients' CPU {r['client_cpu_s']:.1f} s"
        print(f"/api/listen, {r['sessions']} session(s) (stream delay {r['delay_s'] * 1000:.0f} ms, "
              f"{r['failed']} failed, "
              f"{r['wall_s']:.1f} s wall{cpu}): frame delay p50 {r['p50_ms']:.1f} ms, p95 {r['p95_ms']:.1f} ms, "
              f"max {r['max_ms']:.1f} ms over {r['frames']} frames; {r['warnings']} warnings")
        for text in r["warning_examples"] + r["failures"]:
            print(f"  {text}")


if __name__ == "__main__":
    sys.exit(main())
