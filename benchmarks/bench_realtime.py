"""How fast ``/api/listen`` answers a voice service's timings and a barge-in.

    OMP_NUM_THREADS=1 python benchmarks/bench_realtime.py [--repeats 5]

Runs the server in-process (Starlette's TestClient, the shipped stream and audio models) and
relays the recorded Azure fixture of ``examples/realtime`` (PCM with word boundaries), timing
each ``words`` message from sending it to receiving its frames (the first word of each run,
which loads espeak-ng's word cache, left out); then, after the last word, a ``cancel`` to its
``cancelled`` answer; and the same cancel halfway through the OpenAI fixture (PCM alone,
animated by the audio model). Prints p50 / p95 / max in milliseconds.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import time
from pathlib import Path

from fastapi.testclient import TestClient

from vispeech.serve import ServeConfig, create_app

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "realtime" / "relay.py"


def _relay_module():
    spec = importlib.util.spec_from_file_location("relay", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _answer(ws, kind: str) -> None:
    """Receive up to the next message of ``kind``."""
    while ws.receive_json()["type"] != kind:
        pass


def _cancel(ws) -> float:
    started = time.perf_counter()
    ws.send_text(json.dumps({"type": "cancel"}))
    _answer(ws, "cancelled")
    return (time.perf_counter() - started) * 1e3


def _summary(name: str, times: list[float]) -> str:
    ordered = sorted(times)
    p95 = ordered[min(len(ordered) - 1, round(0.95 * (len(ordered) - 1)))]
    return f"{name:34s} p50 {statistics.median(times):6.1f}  p95 {p95:6.1f}  max {max(times):6.1f} ms  (n={len(times)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    relay = _relay_module()
    words, cancels_timed, cancels_audio = [], [], []
    with TestClient(create_app(ServeConfig(cache=":memory:", rate_limit=0))) as client:
        for _ in range(args.repeats):
            messages = list(relay.messages_for("azure"))
            with client.websocket_connect("/api/listen") as ws:
                ws.send_text(messages[0])
                _answer(ws, "start")
                timed = []
                for message in messages[1:-1]:
                    if isinstance(message, bytes):
                        ws.send_bytes(message)
                    elif json.loads(message)["words"][0]["text"] != ".":  # a punctuation boundary makes no frames
                        started = time.perf_counter()
                        ws.send_text(message)
                        _answer(ws, "frames")
                        timed.append((time.perf_counter() - started) * 1e3)
                words += timed[1:]
                cancels_timed.append(_cancel(ws))
            messages = list(relay.messages_for("openai"))
            with client.websocket_connect("/api/listen") as ws:
                for message in messages[: len(messages) // 2]:
                    (ws.send_bytes if isinstance(message, bytes) else ws.send_text)(message)
                _answer(ws, "start")
                cancels_audio.append(_cancel(ws))
    print(_summary("words message to its frames", words))
    print(_summary("cancel to cancelled (words)", cancels_timed))
    print(_summary("cancel to cancelled (audio alone)", cancels_audio))


if __name__ == "__main__":
    main()
