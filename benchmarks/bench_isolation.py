"""What running native work in supervised worker processes (vispeech.frontends.isolation) costs.

    OMP_NUM_THREADS=1 python benchmarks/bench_isolation.py [--repeats 200]

Times the same calls in a worker process (as vispeech runs them) and in this process (the
worker bypassed), alternating, after a warm-up: espeak-ng synthesis of a sentence as ``say``
and ``/api/speak`` run it (the library loaded afresh) and as a text stream's clause does (kept
loaded), ``pipeline.speak`` end to end (what an uncached ``/api/speak`` computes), and an
upload's header and decoding (``/api/animate``), and a job that does nothing (the round trip
alone). A phone stream's messages run no native code
and pay nothing. Also the first call's cost (starting the pool).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import vispeech.frontends.audio as audio
import vispeech.frontends.espeak as espeak
from vispeech.frontends import isolation
from vispeech.pipeline import speak

TEXT = "Hello, how can I help you today?"


def _in_process(library: str, what: str, fn, *args):
    return fn(*args)


def _times(call: Callable[[], object], repeats: int, isolated: bool) -> list[float]:
    runner = isolation.run_isolated if isolated else _in_process
    espeak.run_isolated = audio.run_isolated = runner  # type: ignore[assignment]
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        times.append((time.perf_counter() - started) * 1e3)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()

    started = time.perf_counter()
    espeak.synthesize(TEXT, "en")
    print(f"first call (the pool starts, one worker forked): {(time.perf_counter() - started) * 1e3:.0f} ms")
    wav = speak(TEXT, "en", model="grid-tdnn").wav_bytes()
    assert wav is not None
    cases: dict[str, Callable[[], object]] = {
        "round trip, no work": lambda: espeak.run_isolated("len", "a text", len, TEXT),
        "synthesize (say, /api/speak)": lambda: espeak.synthesize(TEXT, "en"),
        "synthesize (stream clause)": lambda: espeak.synthesize(TEXT, "en", reproducible=False),
        "pipeline.speak grid-tdnn": lambda: speak(TEXT, "en", model="grid-tdnn"),
        f"upload probe + decode ({len(wav) // 1024} KiB WAV)": lambda: audio.read_upload(wav)
        and audio.probe_upload(wav),
    }
    print(f"{'call':42s} {'isolated p50':>13s} {'in-process p50':>15s} {'cost p50':>9s} {'isolated p95':>13s} "
          f"{'in-process p95':>15s}   (ms, {args.repeats} calls each)")
    for name, call in cases.items():
        for isolated in (True, False):
            _times(call, 5, isolated)  # warm-up
        isolated_ms, local_ms = [], []
        for _ in range(args.repeats // 10):  # alternating blocks, so drift hits both alike
            isolated_ms += _times(call, 10, True)
            local_ms += _times(call, 10, False)
        p50 = statistics.median(isolated_ms), statistics.median(local_ms)
        p95 = (statistics.quantiles(isolated_ms, n=20)[-1], statistics.quantiles(local_ms, n=20)[-1])
        print(f"{name:42s} {p50[0]:13.2f} {p50[1]:15.2f} {p50[0] - p50[1]:+9.2f} {p95[0]:13.2f} {p95[1]:15.2f}")


if __name__ == "__main__":
    main()
