"""Can a few addresses hoard every WebSocket slot? 500 sockets from 63 addresses against `vispeech serve`.

    python benchmarks/hoard_slots.py [--sockets 500] [--addresses 63] [--every 20] [--clients 9]
                                     [--seconds 40] [-- SERVER OPTIONS...]

Starts `vispeech serve` on 127.0.0.1 (its default limits: 500 WebSockets, 8 per address, 32
per network; a temporary cache), then opens ``--sockets`` WebSocket connections to
``/api/stream`` from ``--addresses`` loopback addresses, each in a /24 of its own (127.10.x.1),
which send an invalid message (``{}``) at once and every ``--every`` s and reopen at once when
the server closes them (an attacker holding the slots). Once they are open, a new client
every 2 s, each from a fresh address (127.20.k.1), connects, sends a short text and is timed
to its first frames (served) and its end. Prints the hoarders open when the new clients came,
how often the server closed a hoarder, and each new client's time to first frames.

Target (issue 24): every new client served within 1 s. Loopback only: do not point it at a
server of anyone else.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
import time

from local_server import running_server
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus


async def hoarder(i: int, addresses: int, url: str, every: float, stop: asyncio.Event, stats: dict) -> None:
    """One socket of the attacker: open, an invalid message every ``every`` s, reopen when closed."""
    ip = f"127.10.{i % addresses}.1"
    while not stop.is_set():
        try:
            async with connect(url, local_addr=(ip, 0), open_timeout=10) as ws:
                stats["open"] += 1
                try:
                    while not stop.is_set():
                        await ws.send("{}")
                        deadline = time.monotonic() + every
                        while (left := deadline - time.monotonic()) > 0 and not stop.is_set():
                            try:
                                reply = json.loads(await asyncio.wait_for(ws.recv(), timeout=min(left, 1.0)))
                            except TimeoutError:
                                continue
                            key = reply.get("message", reply["type"])[:50]
                            stats["errors"][key] = stats["errors"].get(key, 0) + 1
                finally:
                    stats["open"] -= 1
        except (ConnectionClosed, OSError, TimeoutError, InvalidStatus) as exc:
            code = getattr(getattr(exc, "rcvd", None), "code", None)
            stats["closed_by_server"][str(code)] = stats["closed_by_server"].get(str(code), 0) + 1
            await asyncio.sleep(0.05)


async def new_client(k: int, url: str) -> dict:
    record: dict = {"k": k}
    started = time.perf_counter()
    try:
        async with connect(url, local_addr=(f"127.20.{k}.1", 0), max_size=None, open_timeout=10) as ws:
            record["connected_s"] = time.perf_counter() - started
            await ws.send(json.dumps({"type": "text", "text": f"Hello, visitor number {k}."}))
            while True:
                reply = json.loads(await asyncio.wait_for(ws.recv(), timeout=30))
                if reply["type"] == "frames" and "first_frames_s" not in record:
                    record["first_frames_s"] = time.perf_counter() - started
                if reply["type"] in ("end", "error"):
                    record["end_s"] = time.perf_counter() - started
                    if reply["type"] == "error":
                        record["error"] = reply["message"][:200]
                    return record
    except (ConnectionClosed, OSError, TimeoutError, InvalidStatus) as exc:
        record["error"] = repr(exc)[:200]
    return record


async def attack(url: str, args) -> dict:
    stats: dict = {"open": 0, "closed_by_server": {}, "errors": {}}
    stop = asyncio.Event()
    tasks = [asyncio.create_task(hoarder(i, args.addresses, url, args.every, stop, stats))
             for i in range(args.sockets)]
    began = time.monotonic()
    while stats["open"] < min(args.sockets, 500) and time.monotonic() - began < args.seconds:
        await asyncio.sleep(0.2)
    report = {"hoarders_open_after_s": round(time.monotonic() - began, 1), "hoarders_open": stats["open"],
              "clients": []}
    for k in range(args.clients):
        report["hoarders_open_before_client"] = stats["open"]
        report["clients"].append(await new_client(k, url))
        await asyncio.sleep(2.0)
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    report.update(closed_by_server=stats["closed_by_server"], errors=stats["errors"])
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sockets", type=int, default=500)
    parser.add_argument("--addresses", type=int, default=63)
    parser.add_argument("--every", type=float, default=20.0, help="seconds between a hoarder's invalid messages")
    parser.add_argument("--clients", type=int, default=9)
    parser.add_argument("--seconds", type=float, default=40.0, help="the most to wait for the hoarders to open")
    parser.add_argument("server_options", nargs="*", help="options for `vispeech serve` (after --)")
    args = parser.parse_args()
    args.sockets, args.addresses = min(max(args.sockets, 1), 2000), min(max(args.addresses, 1), 250)
    args.clients = min(max(args.clients, 1), 250)
    signal.signal(signal.SIGALRM, lambda *_: sys.exit("deadline passed"))
    signal.alarm(int(args.seconds + 3 * args.clients + 120))
    with running_server(*args.server_options) as server:
        report = asyncio.run(attack(server.stream_url, args))
        tracebacks = server.log.read_text(errors="replace").count("Traceback")
    served = [c["first_frames_s"] for c in report["clients"] if "first_frames_s" in c]
    print(f"{args.sockets} hoarding sockets from {args.addresses} addresses (an invalid message every "
          f"{args.every:g} s): {report['hoarders_open']} open after {report['hoarders_open_after_s']} s")
    print(f"new clients: {len(served)} of {args.clients} served; first frames "
          + ", ".join(f"{s * 1000:.0f}" for s in served) + " ms"
          + (f"; max {max(served) * 1000:.0f} ms" if served else ""))
    for client in report["clients"]:
        if "error" in client:
            print(f"  client {client['k']}: {client['error']}")
    print(f"hoarders closed by the server (by close code): {report['closed_by_server']}; "
          f"errors they got: {report['errors']}; server tracebacks: {tracebacks}")
    return 0 if len(served) == args.clients and max(served) <= 1.0 else 1


if __name__ == "__main__":
    sys.exit(main())
