"""Latency of each kind of work alone and under a mixed load: text streams, phone streams, uploads, chats.

    python benchmarks/mixed_load.py [--text 15] [--phones 10] [--uploads 5] [--chats 10]
                                    [--seconds 30] [--runs 3] [--json OUT] [-- SERVER OPTIONS...]

Starts `vispeech serve` on 127.0.0.1 (no rate limit, a temporary cache, the default work pool),
then times four kinds of work, each client from a loopback address of its own (127.30.k.1,
each in a /24 of its own, as distinct clients would be):

- text: a text stream (``/api/stream``) of a three-sentence reply: time to the first frames
  (``first``) and to the end (``done``);
- phones: a phone stream of one 20-s phones message with ``"final": true``: time to its
  ``end`` (the issue's measurement: 0.9 s alone, 14-23 s beside 15 text streams);
- upload: ``POST /api/animate`` of a 4-s WAV with its transcript (each one a new file, so
  the cache does not answer it);
- chat: ``POST /api/chat``, the reply spoken (each at its own rate, so it is not cached).

First each kind alone, ``--runs`` times after a warm-up; then all the clients at once, each
repeating its kind of work for ``--seconds``. Prints p50 / p95 / max per kind (ms) alone and
mixed, how many finished, and how many were still unfinished when the time was up (waited
for ``--grace`` s more). Targets (issue 24): every phone message done within 2 s, text first
frames p95 <= 300 ms under the mixed load.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time

import httpx
import numpy as np
from local_server import LocalServer, running_server
from websockets.asyncio.client import connect

from vispeech.frontends.audio import wav_bytes
from vispeech.frontends.espeak import synthesize

TEXT = ("Hello, and welcome! I can answer your questions about opening hours, prices and parking. "
        "What would you like to know?")
PHONE_TEXT = ("Our shop opens at nine in the morning and closes at six in the evening, every day but Sunday. "
              "Parking is free for the first two hours, and after that it costs two euros an hour. "
              "You can pay at the machine by the entrance, or with the app on your phone. "
              "If you have any other questions, just ask me, and I will do my best to answer them.")
UPLOAD_TEXT = "Parking is free for the first two hours."
MESSAGE_SECONDS = 20.0
KINDS = ("text", "phones", "upload", "chat")


class Work:
    """What the clients send: the phones of a 20-s message, an upload's samples."""

    def __init__(self) -> None:
        speech = synthesize(PHONE_TEXT + " " + PHONE_TEXT, "en")
        self.phones = [{"symbol": p.symbol, "start": p.start, "end": p.end, "stress": p.stress}
                       for p in speech.phones if p.end <= MESSAGE_SECONDS]
        upload = synthesize(UPLOAD_TEXT, "en")
        self.upload_samples, self.upload_rate = upload.audio, upload.sample_rate
        self.count = 0

    def upload(self) -> bytes:
        """A new WAV file each time (one sample differs), so the cache never answers it."""
        self.count += 1
        samples = self.upload_samples.copy()
        samples[self.count % len(samples)] += 1e-3 * (1 + self.count % 7)
        samples[(self.count * 7919) % len(samples)] -= 1e-3
        return wav_bytes(samples, self.upload_rate)

    def rate(self) -> float:
        """A speaking rate of its own for each chat (the rate is part of the cache key)."""
        self.count += 1
        return round(0.8 + (self.count % 4000) * 1e-4, 4)


async def text_stream(server: LocalServer, ip: str, work: Work) -> dict:
    async with connect(server.stream_url, local_addr=(ip, 0), max_size=None, open_timeout=60) as ws:
        sent = time.perf_counter()
        await ws.send(json.dumps({"type": "text", "text": TEXT, "language": "en"}))
        first = None
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "frames" and first is None:
                first = time.perf_counter() - sent
            elif message["type"] == "error":
                raise RuntimeError(message["message"])
            elif message["type"] == "end":
                return {"first": first, "done": time.perf_counter() - sent}
    raise RuntimeError("the text stream closed before its end")


async def phone_stream(server: LocalServer, ip: str, work: Work) -> dict:
    async with connect(server.stream_url, local_addr=(ip, 0), max_size=None, open_timeout=60) as ws:
        sent = time.perf_counter()
        await ws.send(json.dumps({"type": "phones", "phones": work.phones, "language": "en", "final": True}))
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] == "error":
                raise RuntimeError(message["message"])
            if message["type"] == "end":
                return {"done": time.perf_counter() - sent}
    raise RuntimeError("the phone stream closed before its end")


async def post(server: LocalServer, ip: str, path: str, **request) -> float:
    transport = httpx.AsyncHTTPTransport(local_address=ip)
    async with httpx.AsyncClient(transport=transport, base_url=server.url, timeout=120) as client:
        sent = time.perf_counter()
        response = await client.post(path, **request)
        if response.status_code != 200:
            raise RuntimeError(f"{path}: {response.status_code} {response.text[:200]}")
        return time.perf_counter() - sent


async def upload(server: LocalServer, ip: str, work: Work) -> dict:
    body = work.upload()
    return {"done": await post(server, ip, "/api/animate", params={"text": UPLOAD_TEXT}, content=body,
                               headers={"Content-Type": "audio/wav"})}


async def chat(server: LocalServer, ip: str, work: Work) -> dict:
    request = {"message": "When do you open?", "language": "en", "rate": work.rate()}
    return {"done": await post(server, ip, "/api/chat", json=request)}


CLIENTS = {"text": text_stream, "phones": phone_stream, "upload": upload, "chat": chat}


def summary(records: list[dict], unfinished: int = 0, failures: list[str] | None = None) -> dict:
    out: dict = {"finished": len(records), "unfinished": unfinished, "failed": len(failures or []),
                 "failures": (failures or [])[:3]}
    for measure in ("first", "done"):
        values = [r[measure] for r in records if r.get(measure) is not None]
        if values:
            out[measure] = {f"p{q}": round(float(np.percentile(values, q)) * 1000, 1) for q in (50, 95)}
            out[measure]["max"] = round(max(values) * 1000, 1)
    return out


async def alone(server: LocalServer, work: Work, runs: int) -> dict:
    report = {}
    for k, kind in enumerate(KINDS):
        ip = f"127.31.{k}.1"
        await CLIENTS[kind](server, ip, work)  # warm-up
        report[kind] = summary([await CLIENTS[kind](server, ip, work) for _ in range(runs)])
    return report


async def mixed(server: LocalServer, work: Work, counts: dict[str, int], seconds: float, grace: float) -> dict:
    records: dict[str, list[dict]] = {kind: [] for kind in KINDS}
    failures: dict[str, list[str]] = {kind: [] for kind in KINDS}
    unfinished = dict.fromkeys(KINDS, 0)
    end = time.perf_counter() + seconds

    async def client(kind: str, ip: str) -> None:
        while time.perf_counter() < end:
            task = asyncio.ensure_future(CLIENTS[kind](server, ip, work))
            try:
                records[kind].append(await asyncio.wait_for(task, max(0.1, end + grace - time.perf_counter())))
            except TimeoutError:
                unfinished[kind] += 1
                return
            except Exception as exc:  # noqa: BLE001 (counted and shown)
                failures[kind].append(repr(exc)[:200])
                await asyncio.sleep(0.5)

    kinds = [kind for kind in KINDS for _ in range(counts[kind])]
    await asyncio.gather(*(client(kind, f"127.30.{i}.1") for i, kind in enumerate(kinds)))
    return {kind: summary(records[kind], unfinished[kind], failures[kind]) for kind in KINDS}


def show(title: str, report: dict) -> None:
    print(title)
    for kind, figures in report.items():
        parts = [f"{m} p50 {f['p50']:7.0f} p95 {f['p95']:7.0f} max {f['max']:7.0f} ms"
                 for m in ("first", "done") if (f := figures.get(m))]
        state = f"{figures['finished']} done"
        if figures["unfinished"] or figures["failed"]:
            state += f", {figures['unfinished']} unfinished, {figures['failed']} failed"
        print(f"  {kind:7s} {'; '.join(parts)}  ({state})")
        for failure in figures["failures"]:
            print(f"    failure: {failure}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for kind, default in (("text", 15), ("phones", 10), ("uploads", 5), ("chats", 10)):
        parser.add_argument(f"--{kind}", type=int, default=default, help=f"{kind} clients in the mixed load")
    parser.add_argument("--seconds", type=float, default=30.0, help="how long the mixed load runs")
    parser.add_argument("--grace", type=float, default=30.0, help="seconds to wait for unfinished work after")
    parser.add_argument("--runs", type=int, default=3, help="runs of each kind alone")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("server", nargs="*", help="options for vispeech serve (after --)")
    args = parser.parse_args()
    counts = {"text": args.text, "phones": args.phones, "upload": args.uploads, "chat": args.chats}
    work = Work()

    async def both(server: LocalServer) -> dict:
        report = {"alone": await alone(server, work, args.runs)}
        cpu = server.cpu_seconds()
        report["mixed"] = await mixed(server, work, counts, args.seconds, args.grace)
        report["mixed_server_cpu_s"] = None if cpu is None else round(server.cpu_seconds() - cpu, 1)
        return report

    with running_server("--rate-limit", "0", *args.server) as server:
        report = asyncio.run(both(server))
    show(f"alone ({args.runs} runs each):", report["alone"])
    show(f"mixed ({', '.join(f'{n} {kind}' for kind, n in counts.items())} clients for {args.seconds:g} s, "
         f"server CPU {report['mixed_server_cpu_s']} s):", report["mixed"])
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump({"counts": counts, "seconds": args.seconds, **report}, handle, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
