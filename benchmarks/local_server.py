"""A `vispeech serve` subprocess on 127.0.0.1 for the server benchmarks (load_stream, fuzz_server).

The server listens on a free loopback port, keeps its cache in a temporary folder and is
stopped (terminate, then kill after 10 s) when the ``with`` block ends, however it ends.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class LocalServer:
    url: str
    """Base URL, ``http://127.0.0.1:<port>``."""
    log: Path
    """The server's output so far (stdout and stderr)."""

    pid: int

    @property
    def stream_url(self) -> str:
        return self.url.replace("http://", "ws://") + "/api/stream"

    def cpu_seconds(self) -> float | None:
        """User + system CPU time the server process and its live child processes (``--processes``)
        have used (Linux only, else ``None``)."""
        total, found = 0, False
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if stat.parent.name == str(self.pid) or fields[1] == str(self.pid):
                total += int(fields[11]) + int(fields[12])
                found = True
        return total / os.sysconf("SC_CLK_TCK") if found else None


@contextmanager
def running_server(*options: str, startup_timeout: float = 60.0) -> Iterator[LocalServer]:
    """Start `vispeech serve OPTIONS` on a free loopback port and yield it."""
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="vispeech-serve-") as tmp:
        log = open(Path(tmp) / "server.log", "wb")
        command = [sys.executable, "-c", "from vispeech.cli import main; main()", "serve",
                   "--host", "127.0.0.1", "--port", str(port), "--cache", str(Path(tmp) / "cache.sqlite3"),
                   "--log-level", "warning", *options]
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        url = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + startup_timeout
            while True:
                if process.poll() is not None:
                    raise RuntimeError(f"the server exited with code {process.returncode}: "
                                       + (Path(tmp) / "server.log").read_text(errors="replace")[-2000:])
                try:
                    with urllib.request.urlopen(f"{url}/api/config", timeout=2) as response:
                        if response.status == 200:
                            break
                except OSError:
                    pass
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the server did not answer within {startup_timeout:g} s")
                time.sleep(0.2)
            yield LocalServer(url, Path(tmp) / "server.log", process.pid)
        finally:
            process.terminate()
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            log.close()
