"""``vispeech serve --processes N``: the settings handed to every process, the processes
answering on one port over one SQLite cache."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("uvicorn", "uvicorn (the serve extra)")

from vispeech.errors import VispeechError  # noqa: E402
from vispeech.serve import HTTPChatBot, RuleBot, ServeConfig  # noqa: E402


def test_settings_round_trip_through_json(tmp_path):
    config = ServeConfig(avatar=tmp_path / "head.glb", cache=str(tmp_path / "c.sqlite3"), rate_limit=0.5,
                         allowed_hosts=("localhost", "example.org"), allowed_origins=None, token="s3cret",
                         bot=HTTPChatBot("http://127.0.0.1:9/chat", reply_field="choices.0.text", timeout=3.0),
                         workers=3, max_streams=7)
    back = ServeConfig.from_json(config.to_json())
    assert {k: v for k, v in vars(back).items() if k != "bot"} == {k: v for k, v in vars(config).items() if k != "bot"}
    assert isinstance(back.bot, HTTPChatBot) and vars(back.bot) == vars(config.bot)
    assert isinstance(ServeConfig.from_json(ServeConfig().to_json()).bot, RuleBot)


def test_a_custom_bot_cannot_go_to_other_processes():
    class EchoBot:
        def reply(self, message: str, lang: str) -> str:
            return message

    with pytest.raises(VispeechError, match="cannot be handed to other server processes"):
        ServeConfig(bot=EchoBot()).to_json()


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if stat.read_text().rsplit(")", 1)[1].split()[1] == str(pid):
                found.append(int(stat.parent.name))
        except (OSError, IndexError):
            continue
    return found


def test_two_processes_serve_one_port_and_one_cache(tmp_path):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cache = tmp_path / "cache.sqlite3"
    log = open(tmp_path / "server.log", "wb")
    server = subprocess.Popen([sys.executable, "-c", "from vispeech.cli import main; main()", "serve", "--port",
                               str(port), "--cache", str(cache), "--processes", "2", "--rate-limit", "0",
                               "--log-level", "warning"], stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            assert server.poll() is None, (tmp_path / "server.log").read_text(errors="replace")[-2000:]
            try:
                with urllib.request.urlopen(f"{url}/api/config", timeout=2) as response:
                    if response.status == 200:
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline, "the server did not start"
            time.sleep(0.3)
        if sys.platform.startswith("linux"):
            deadline = time.monotonic() + 120
            while len(_children(server.pid)) < 2 and time.monotonic() < deadline:
                time.sleep(0.3)
            assert len(_children(server.pid)) >= 2  # the two worker processes under the supervisor

        def speak(text: str) -> dict:
            request = urllib.request.Request(f"{url}/api/speak", data=json.dumps({"text": text, "lang": "en"}).encode(),
                                             headers={"Content-Type": "application/json"})
            with urllib.request.urlopen(request, timeout=60) as response:
                return json.load(response)

        answers = [speak(f"Line {i} of the test.") for i in range(6)]
        assert all(a["animation"]["frames"] for a in answers)
        again = speak("Line 3 of the test.")  # cached by whichever process made it: one shared cache
        assert again["audio_url"] == answers[3]["audio_url"]
        with urllib.request.urlopen(f"{url}{answers[0]['audio_url']}", timeout=30) as response:
            assert response.read(4) == b"RIFF"
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
        log.close()
