"""What one long upload costs everyone else: ``/api/speak`` latency beside a 10-minute recording.

    python benchmarks/long_upload.py [--seconds 590] [--requests 10] [--json OUT] [-- SERVER OPTIONS...]

Starts `vispeech serve` on 127.0.0.1 (no rate limit, the default work pool: one worker on two
cores), times ``--requests`` short ``/api/speak`` requests alone, then uploads ``--seconds`` of
espeak-ng speech to ``/api/animate`` (no transcript: the default audio model) from one address
while another address sends the same kind of request again and again until the upload is
answered. Prints the upload's time and the requests' p50 / p95 / max (ms) alone and beside it.
A long job gives the worker to the short jobs waiting between its pieces
(:mod:`vispeech.turns`); without that, each request beside the upload waited for all of it.
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

from vispeech.frontends.audio import wav_bytes
from vispeech.frontends.espeak import synthesize

PARAGRAPH = ("Our shop opens at nine in the morning and closes at six in the evening, every day but Sunday. "
             "Parking is free for the first two hours, and after that it costs two euros an hour.")


def recording(seconds: float) -> bytes:
    """``seconds`` of espeak-ng speech as a WAV file."""
    speech = synthesize(PARAGRAPH, "en")
    samples = np.tile(speech.audio, int(np.ceil(seconds * speech.sample_rate / len(speech.audio))))
    return wav_bytes(samples[: round(seconds * speech.sample_rate)], speech.sample_rate)


async def speak(client: httpx.AsyncClient, k: int) -> float:
    """Seconds one ``/api/speak`` of a sentence never asked before took."""
    sent = time.perf_counter()
    response = await client.post("/api/speak", json={"text": f"Ticket number {k} is ready.", "language": "en"})
    if response.status_code != 200:
        raise RuntimeError(f"/api/speak: {response.status_code} {response.text[:200]}")
    return time.perf_counter() - sent


def figures(latencies: list[float]) -> dict:
    ms = np.array(latencies) * 1000
    return {"requests": len(ms), "p50": round(float(np.percentile(ms, 50)), 1),
            "p95": round(float(np.percentile(ms, 95)), 1), "max": round(float(ms.max()), 1)}


async def measure(server: LocalServer, seconds: float, requests: int) -> dict:
    body = recording(seconds)
    speaker = httpx.AsyncClient(base_url=server.url, timeout=600,
                                transport=httpx.AsyncHTTPTransport(local_address="127.30.1.1"))
    uploader = httpx.AsyncClient(base_url=server.url, timeout=600,
                                 transport=httpx.AsyncHTTPTransport(local_address="127.30.2.1"))
    async with speaker, uploader:
        await speak(speaker, -1)  # warm-up
        alone = [await speak(speaker, k) for k in range(requests)]
        sent = time.perf_counter()
        upload = asyncio.ensure_future(
            uploader.post("/api/animate", content=body, headers={"Content-Type": "audio/wav"})
        )
        beside, k = [], requests
        while not upload.done():
            beside.append(await speak(speaker, k))
            k += 1
            await asyncio.sleep(0.25)
        response = await upload
        if response.status_code != 200:
            raise RuntimeError(f"/api/animate: {response.status_code} {response.text[:200]}")
        took = time.perf_counter() - sent
    return {"upload_seconds": seconds, "upload_took_s": round(took, 2), "alone": figures(alone),
            "beside": figures(beside)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=590.0, help="length of the uploaded recording")
    parser.add_argument("--requests", type=int, default=10, help="requests timed alone")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("server", nargs="*", help="options for vispeech serve (after --)")
    args = parser.parse_args()
    with running_server("--rate-limit", "0", *args.server) as server:
        report = asyncio.run(measure(server, args.seconds, args.requests))
    print(f"upload of {args.seconds:g} s answered in {report['upload_took_s']:.1f} s")
    for name in ("alone", "beside"):
        f = report[name]
        print(f"/api/speak {name:>6}: {f['requests']:3d} requests, p50 {f['p50']:7.0f}  p95 {f['p95']:7.0f}  "
              f"max {f['max']:7.0f} ms")
    if args.json:
        with open(args.json, "w") as out:
            json.dump(report, out, indent=1)


if __name__ == "__main__":
    sys.exit(main())
