"""``vispeech serve --processes N``: the settings handed to every process, the processes
answering on one port over one SQLite cache."""

from __future__ import annotations

import json
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import require_module

require_module("fastapi", "fastapi (the serve extra)")
require_module("uvicorn", "uvicorn (the serve extra)")

from vispeech.errors import VispeechError  # noqa: E402
from vispeech.serve import OpenAIChatBot, RuleBot, ServeConfig  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from local_server import running_server  # noqa: E402  (the benchmarks' `vispeech serve` subprocess)


def test_settings_round_trip_through_json(tmp_path):
    config = ServeConfig(avatar=tmp_path / "head.glb", cache=str(tmp_path / "c.sqlite3"), rate_limit=0.5,
                         allowed_hosts=("localhost", "example.org"), allowed_origins=None, token="s3cret",
                         bot=OpenAIChatBot("http://127.0.0.1:9/v1", "llm", key="k", system="Be brief.", timeout=3.0),
                         reply_languages=("en", "de"),
                         workers=3, max_streams=7)
    back = ServeConfig.from_json(config.to_json())
    assert {k: v for k, v in vars(back).items() if k != "bot"} == {k: v for k, v in vars(config).items() if k != "bot"}
    assert isinstance(back.bot, OpenAIChatBot) and vars(back.bot) == vars(config.bot)
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


def test_two_processes_serve_one_port_and_one_cache():
    with running_server("--processes", "2", "--rate-limit", "0", startup_timeout=180) as server:
        if sys.platform.startswith("linux"):
            deadline = time.monotonic() + 120
            while len(_children(server.pid)) < 2 and time.monotonic() < deadline:
                time.sleep(0.3)
            assert len(_children(server.pid)) >= 2  # the two worker processes under the supervisor

        def speak(text: str) -> dict:
            request = urllib.request.Request(f"{server.url}/api/speak",
                                             data=json.dumps({"text": text, "language": "en"}).encode(),
                                             headers={"Content-Type": "application/json"})
            with urllib.request.urlopen(request, timeout=60) as response:
                return json.load(response)

        answers = [speak(f"Line {i} of the test.") for i in range(6)]
        assert all(a["animation"]["frames"] for a in answers)
        again = speak("Line 3 of the test.")  # cached by whichever process made it: one shared cache
        assert again["audio_url"] == answers[3]["audio_url"]
        with urllib.request.urlopen(f"{server.url}{answers[0]['audio_url']}", timeout=30) as response:
            assert response.read(4) == b"RIFF"
