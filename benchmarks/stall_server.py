"""Can a few clients stall the server? 50 heavy clients and 200 idle sockets against `vispeech serve`.

    python benchmarks/stall_server.py [--seconds 60] [--heavy 50] [--idle 200] [--message phones|text]
                                      [--json OUT] [-- SERVER OPTIONS...]

Starts `vispeech serve` on 127.0.0.1 on a free port in a subprocess with its default limits
(a temporary cache), then for ``--seconds`` runs, in a second process:

- ``--heavy`` clients, each sending the most expensive stream message the limits allow, as
  fast as the rate limit lets it: ``phones`` (the default): 500 phones adding 20 s to a phone
  stream (the most a message may add), the next message as soon as its frames are in (after a
  rate-limit or busy error: 1 s later); ``text``: 1000 characters without punctuation (one
  clause, the longest single job);
- ``--idle`` WebSocket connections that never send anything (reopened when the server closes
  them for idleness);

each client from its own loopback address, each heavy one in a /24 of its own (127.1.x.1) and
the idle ones spread over /24s (127.2.x.y), as distinct clients on the network would be, so the
per-address and per-network limits apply to each separately.
Meanwhile this process measures, each from fresh loopback addresses of its own:

- ``GET /api/config`` every 100 ms: p50 / p95 / max latency;
- a new client every 2 s: a WebSocket connection sending a short text, timed to its first
  frames (served) and to its end; and a ``POST /api/speak`` of a new short text;
- the server's CPU (``/proc/<pid>/stat``) during the load and in each second after the load
  process exits (its sockets closed by the kernel: the clients leave at once).

Targets (issue 8): config p95 <= 200 ms, a new client served within 1 s, the server's CPU
idle within 2 s of the clients leaving. Everything stops by itself (``--deadline``).
Loopback only: do not point it at a server of anyone else.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
from local_server import running_server
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

SYMBOLS = ["AA1", "M", "IY1", "S", "OW1", "P", "AE1", "T", "UW1", "L"]
MESSAGE_SECONDS = 20.0
"""What one phones message may add (ServeConfig.max_message_seconds)."""
STREAM_SECONDS = 600.0
MAX_PHONES = 500


def phones_message(start: float) -> str:
    step = MESSAGE_SECONDS / MAX_PHONES
    phones = [{"symbol": SYMBOLS[i % len(SYMBOLS)], "start": round(start + i * step, 6),
               "end": round(start + (i + 1) * step, 6)} for i in range(MAX_PHONES)]
    return json.dumps({"type": "phones", "language": "en", "phones": phones})


LONG_TEXT = ("hello there my friend how are you doing on this fine day " * 20)[:1000].strip()


# -- the load (its own process) ----------------------------------------------------------------------

async def heavy_client(i: int, url: str, end: float, kind: str, stats: dict) -> None:
    ip = f"127.1.{i}.1"
    while time.monotonic() < end:
        try:
            async with connect(url, local_addr=(ip, 0), max_size=None, open_timeout=10) as ws:
                begin, lookahead = 0.0, None
                while time.monotonic() < end and begin + MESSAGE_SECONDS <= STREAM_SECONDS:
                    await ws.send(phones_message(begin) if kind == "phones" else
                                  json.dumps({"type": "text", "text": LONG_TEXT}))
                    stats["sent"] += 1
                    ok = False
                    while True:
                        raw = await asyncio.wait_for(ws.recv(), timeout=max(0.1, end - time.monotonic()))
                        reply = json.loads(raw)
                        if reply["type"] == "start":
                            lookahead = reply.get("lookahead")
                        elif reply["type"] == "frames":
                            stats["frames"] += len(reply["frames"])
                            if kind == "phones" and lookahead is not None and reply["start_frame"] + len(
                                    reply["frames"]) >= round((begin + MESSAGE_SECONDS) * 30) - lookahead:
                                ok = True
                                break
                        elif reply["type"] == "end":
                            ok = True
                            break
                        elif reply["type"] == "error":
                            message = reply["message"]
                            key = "rate_limited" if "rate limit" in message else "busy" if "busy" in message else "errors"
                            stats[key] += 1
                            if key == "errors" and len(stats["error_samples"]) < 5:
                                stats["error_samples"].append(message[:200])
                            break
                    if ok:
                        stats["done"] += 1
                        begin += MESSAGE_SECONDS
                    else:
                        await asyncio.sleep(1.0)
        except (ConnectionClosed, OSError, TimeoutError, InvalidStatus) as exc:
            if time.monotonic() < end:
                stats["heavy_closed"] += 1
                if len(stats["error_samples"]) < 5:
                    stats["error_samples"].append(repr(exc)[:200])
                await asyncio.sleep(0.5)


async def idle_client(j: int, url: str, end: float, stats: dict) -> None:
    ip = f"127.2.{j % 250}.{j // 250 + 1}"
    while time.monotonic() < end:
        try:
            async with connect(url, local_addr=(ip, 0), open_timeout=10) as ws:
                stats["idle_opened"] += 1
                while True:
                    await asyncio.wait_for(ws.recv(), timeout=max(0.1, end - time.monotonic()))
        except TimeoutError:  # the end (an OSError too: caught first)
            return
        except (ConnectionClosed, OSError, InvalidStatus) as exc:
            stats["idle_closed_by_server"] += 1
            if len(stats["idle_samples"]) < 3:
                stats["idle_samples"].append(repr(exc)[:200])
            await asyncio.sleep(0.2)


async def load(url: str, seconds: float, heavy: int, idle: int, kind: str) -> dict:
    stats = {"sent": 0, "done": 0, "frames": 0, "rate_limited": 0, "busy": 0, "errors": 0, "heavy_closed": 0,
             "idle_opened": 0, "idle_closed_by_server": 0, "error_samples": [], "idle_samples": []}
    end = time.monotonic() + seconds
    tasks = [asyncio.create_task(idle_client(j, url, end, stats)) for j in range(idle)]
    tasks += [asyncio.create_task(heavy_client(i, url, end, kind, stats)) for i in range(heavy)]
    await asyncio.wait(tasks, timeout=seconds + 5)
    return stats


def run_load(args) -> int:
    stats = asyncio.run(load(args.url, args.seconds, args.heavy, args.idle, args.message))
    print(json.dumps(stats), flush=True)
    os._exit(0)  # leave at once: the kernel closes every socket, nothing says goodbye


# -- the measurements (this process) -----------------------------------------------------------------

def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def probe_config(base: str, end: float, out: list) -> None:
    transport = httpx.AsyncHTTPTransport(local_address="127.0.4.1")
    async with httpx.AsyncClient(base_url=base, transport=transport, timeout=30) as client:
        while time.monotonic() < end:
            started = time.perf_counter()
            try:
                status = (await client.get("/api/config")).status_code
            except httpx.HTTPError:
                status = None
            out.append((time.monotonic(), time.perf_counter() - started, status))
            await asyncio.sleep(max(0.0, 0.1 - (time.perf_counter() - started)))


async def new_clients(base: str, end: float, out: list) -> None:
    url = base.replace("http://", "ws://") + "/api/stream"
    k = 0
    while time.monotonic() < end:
        k += 1
        ip = f"127.5.{k % 250}.1"
        record = {"k": k}
        started = time.perf_counter()
        try:
            async with connect(url, local_addr=(ip, 0), max_size=None, open_timeout=10) as ws:
                record["connected_s"] = time.perf_counter() - started
                sent = time.perf_counter()
                await ws.send(json.dumps({"type": "text", "text": f"Hello, visitor number {k}."}))
                while True:
                    reply = json.loads(await asyncio.wait_for(ws.recv(), timeout=30))
                    if reply["type"] == "frames" and "first_frames_s" not in record:
                        record["first_frames_s"] = time.perf_counter() - sent
                    if reply["type"] in ("end", "error"):
                        record["end_s"] = time.perf_counter() - sent
                        if reply["type"] == "error":
                            record["error"] = reply["message"][:200]
                        break
        except (ConnectionClosed, OSError, TimeoutError, InvalidStatus) as exc:
            record["error"] = repr(exc)[:200]
        transport = httpx.AsyncHTTPTransport(local_address=f"127.6.{k % 250}.1")
        async with httpx.AsyncClient(base_url=base, transport=transport, timeout=30) as client:
            sent = time.perf_counter()
            try:
                response = await client.post("/api/speak", json={"text": f"Good day, reader number {k}."})
                record["speak_s"], record["speak_status"] = time.perf_counter() - sent, response.status_code
            except httpx.HTTPError as exc:
                record["speak_error"] = repr(exc)[:200]
        out.append(record)
        await asyncio.sleep(max(0.0, 2.0 - (time.perf_counter() - started)))


def percentiles(values: list[float]) -> dict:
    if not values:
        return {"n": 0}
    ms = np.array(values) * 1000.0
    return {"n": len(values), "p50_ms": float(np.percentile(ms, 50)), "p95_ms": float(np.percentile(ms, 95)),
            "max_ms": float(ms.max())}


def measure(args, server) -> dict:
    pid = server.pid
    cpu_before = cpu_seconds(pid)
    load = subprocess.Popen([sys.executable, __file__, "--role", "load", "--url", server.stream_url,
                             "--seconds", str(args.seconds), "--heavy", str(args.heavy), "--idle", str(args.idle),
                             "--message", args.message], stdout=subprocess.PIPE, text=True)
    started = time.monotonic()
    end = started + args.seconds
    config, clients = [], []

    async def both():
        await asyncio.gather(probe_config(server.url, end, config), new_clients(server.url, end, clients))

    asyncio.run(both())
    try:
        output, _ = load.communicate(timeout=args.seconds + 30)
    except subprocess.TimeoutExpired:
        load.kill()
        output, _ = load.communicate()
    left = time.monotonic()
    cpu_left = cpu_seconds(pid)
    after = []
    for _ in range(4):
        time.sleep(1.0)
        after.append(cpu_seconds(pid))
    after_steps = np.diff([cpu_left, *after]).tolist()
    try:
        load_stats = json.loads(output.strip().splitlines()[-1])
    except (ValueError, IndexError):
        load_stats = {"output": output[-500:]}
    with httpx.Client(base_url=server.url, timeout=10) as client:
        t = time.perf_counter()
        final_status = client.get("/api/config").status_code
        quiet_config = time.perf_counter() - t

    latencies = [lat for _, lat, status in config if status == 200]
    windows = []
    for w in range(int(args.seconds // 10)):
        lo, hi = started + 10 * w, started + 10 * (w + 1)
        windows.append(percentiles([lat for at, lat, s in config if lo <= at < hi and s == 200]))
    served = [c["first_frames_s"] for c in clients if "first_frames_s" in c]
    return {
        "seconds": args.seconds, "heavy": args.heavy, "idle": args.idle, "message": args.message,
        "config": {**percentiles(latencies), "failed": sum(1 for _, _, s in config if s != 200),
                   "per_10s": windows},
        "new_clients": {"n": len(clients), "served": len(served), "first_frames": percentiles(served),
                        "end": percentiles([c["end_s"] for c in clients if "end_s" in c and "error" not in c]),
                        "connect": percentiles([c["connected_s"] for c in clients if "connected_s" in c]),
                        "speak": percentiles([c["speak_s"] for c in clients if c.get("speak_status") == 200]),
                        "speak_statuses": sorted({c.get("speak_status") for c in clients}, key=str),
                        "errors": [c["error"] for c in clients if "error" in c][:5]},
        "server_cpu_during_load_s": cpu_left - cpu_before,
        "server_cpu_per_second_after_leaving": after_steps,
        "seconds_to_leave": left - end,
        "load": load_stats,
        "config_after": {"status": final_status, "ms": quiet_config * 1000},
    }


def verdict(report: dict) -> list[str]:
    failures = []
    worst = max([w.get("p95_ms", 0.0) for w in report["config"]["per_10s"]] + [report["config"].get("p95_ms", 0.0)])
    if worst > 200:
        failures.append(f"GET /api/config p95 {worst:.0f} ms > 200 ms")
    if report["config"]["failed"]:
        failures.append(f"{report['config']['failed']} config requests failed")
    nc = report["new_clients"]
    if nc["served"] < nc["n"] or nc["first_frames"].get("max_ms", 0.0) > 1000:
        failures.append(f"new clients: {nc['served']} of {nc['n']} served, slowest {nc['first_frames'].get('max_ms')} ms")
    after = report["server_cpu_per_second_after_leaving"]
    if sum(after[2:]) > 0.1:
        failures.append(f"server CPU after the clients left: {after} s per second")
    return failures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--heavy", type=int, default=50)
    parser.add_argument("--idle", type=int, default=200)
    parser.add_argument("--message", choices=["phones", "text"], default="phones")
    parser.add_argument("--deadline", type=float, default=240.0, help="seconds before everything stops")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--role", choices=["measure", "load"], default="measure", help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("server_options", nargs="*", help="options for `vispeech serve` (after --)")
    args = parser.parse_args()
    args.seconds = min(max(args.seconds, 5.0), 300.0)
    args.heavy, args.idle = min(max(args.heavy, 0), 200), min(max(args.idle, 0), 400)
    if args.role == "load":
        return run_load(args)
    import signal

    signal.signal(signal.SIGALRM, lambda *_: sys.exit("deadline passed"))
    signal.alarm(int(max(args.deadline, args.seconds + 60)))
    with running_server(*args.server_options) as server:
        report = measure(args, server)
        log = server.log.read_text(errors="replace")
    report["server_log_tracebacks"] = log.count("Traceback")
    failures = verdict(report)
    c, nc = report["config"], report["new_clients"]
    print(f"{args.heavy} heavy clients ({args.message}) + {args.idle} idle sockets for {args.seconds:g} s")
    nan = float("nan")
    per_10s = ", ".join(f"{w.get('p95_ms', nan):.0f}" for w in c["per_10s"])
    print(f"GET /api/config: n {c['n']}, p50 {c.get('p50_ms', nan):.1f} ms, p95 {c.get('p95_ms', nan):.1f} ms, "
          f"max {c.get('max_ms', nan):.1f} ms; p95 per 10 s: {per_10s} ms")
    ff = nc["first_frames"]
    print(f"new clients: {nc['served']} of {nc['n']} served; first frames p50 {ff.get('p50_ms', nan):.0f} ms, "
          f"p95 {ff.get('p95_ms', nan):.0f} ms, max {ff.get('max_ms', nan):.0f} ms; "
          f"speak {nc['speak']} statuses {nc['speak_statuses']}")
    print(f"server CPU during the load {report['server_cpu_during_load_s']:.1f} s; per second after the clients left: "
          f"{', '.join(f'{x:.2f}' for x in report['server_cpu_per_second_after_leaving'])} s")
    print(f"load: {json.dumps(report['load'])}")
    print(f"tracebacks in the server log: {report['server_log_tracebacks']}")
    for failure in failures:
        print(f"FAIL {failure}")
    print("ok: every target met" if not failures else f"{len(failures)} targets missed")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2), encoding="utf-8")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
