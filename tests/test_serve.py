"""The HTTP side of the server: speak, cache, config, chat, static files, limits, bad input."""

from __future__ import annotations

import io
import json
import math
import random
import re
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
from conftest import require_module
from scipy.io import wavfile

require_module("fastapi", "fastapi (the serve extra)")
require_module("httpx", "httpx (the test extra)")
from fastapi.testclient import TestClient  # noqa: E402

import vispeech.preview  # noqa: E402
from vispeech.errors import VispeechError  # noqa: E402
from vispeech.pipeline import DEFAULT_MODEL, GREETINGS  # noqa: E402
from vispeech.serve.pages import SWAGGER_UI  # noqa: E402
from vispeech.serve import (  # noqa: E402
    CacheKey, RuleBot, ServeConfig, UtteranceCache, create_app,
)
from vispeech.guards import TokenBucket  # noqa: E402

FACE2D = Path(vispeech.preview.__file__).parent / "face2d.js"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("serve")
    static = root / "static"
    static.mkdir()
    for name in ("index.html", "player.html", "viewer.html"):
        (static / name).write_text(f"<!doctype html><title>{name}</title>", encoding="utf-8")
    (static / "style.css").write_text("body{}", encoding="utf-8")
    (static / "swagger-ui").mkdir()
    for name in SWAGGER_UI.values():
        (static / name).write_text(f"/* {name} */", encoding="utf-8")
    avatar = root / "head.glb"
    avatar.write_bytes(b"glTF\x02\x00\x00\x00" + bytes(range(64)))
    (root / "secret.txt").write_text("root:x:0:0", encoding="utf-8")
    return {"root": root, "static": static, "avatar": avatar, "cache": root / "cache.sqlite3"}


@pytest.fixture(scope="module")
def client(site) -> TestClient:
    config = ServeConfig(avatar=site["avatar"], cache=site["cache"], static_dir=site["static"], rate_limit=0)
    with TestClient(create_app(config)) as client:
        yield client


def test_config(client, site):
    config = client.get("/api/config").json()
    assert config["avatar_url"] == "/avatar.glb"
    assert config["languages"][:2] == ["sv", "en"] and {"de", "cmn", "sw"} <= set(config["languages"])
    assert len(config["languages"]) > 100 and config["language_names"]["de"] == "German"
    assert config["chat_languages"] == ["sv", "en"]  # the rule bot
    assert config["default_model"] == DEFAULT_MODEL and {"baseline", DEFAULT_MODEL} <= set(config["models"])
    assert "tdnn-beskow" not in config["models"]  # untrained networks are not offered
    assert config["fps"] == 30.0 and config["max_text"] == 1000
    assert client.get("/avatar.glb").content == site["avatar"].read_bytes()


def test_speak_gives_audio_and_animation_of_equal_length(client):
    response = client.post("/api/speak", json={"text": "Hello there, how are you?", "language": "en"})
    assert response.status_code == 200
    body = response.json()
    assert body["audio_url"].startswith("/api/audio/") and body["audio_url"].endswith(".wav")
    audio = client.get(body["audio_url"])
    assert audio.status_code == 200 and audio.headers["content-type"] == "audio/wav"
    rate, samples = wavfile.read(io.BytesIO(audio.content))
    animation = body["animation"]
    assert animation["format"] == "vispeech-animation" and animation["fps"] == 30.0
    assert animation["n_frames"] == len(animation["frames"]) == math.ceil(len(samples) / rate * 30.0 - 1e-6)
    assert all(len(row) == len(animation["channels"]) for row in animation["frames"])
    assert animation["phones"]["phones"][-1]["end"] == pytest.approx(len(samples) / rate)
    assert body["cached"] is False


def test_repeated_request_comes_from_the_cache_file(client, site):
    request = {"text": "Hej, hur mår du?", "language": "sv", "rate": 1.2}
    first = client.post("/api/speak", json=request).json()
    second = client.post("/api/speak", json=request).json()
    assert (first["cached"], second["cached"]) == (False, True)
    assert second["audio_url"] == first["audio_url"] and second["animation"] == first["animation"]
    other = client.post("/api/speak", json={**request, "rate": 1.0}).json()
    assert other["cached"] is False and other["audio_url"] != first["audio_url"]
    with TestClient(create_app(ServeConfig(cache=site["cache"], rate_limit=0))) as fresh:  # same file, new server
        again = fresh.post("/api/speak", json=request).json()
        assert again["cached"] is True and fresh.get(again["audio_url"]).status_code == 200


def test_speak_adds_the_non_verbal_layers_asked_for(client):
    request = {"text": "Hello there. How are you today?", "language": "en"}
    plain = client.post("/api/speak", json=request).json()
    assert not {"eyeBlinkLeft", "headYaw", "breath"} & set(plain["animation"]["channels"])
    lively = client.post("/api/speak", json={**request, "life": ["head", "blink"], "seed": 7}).json()
    again = client.post("/api/speak", json={**request, "life": ["blink", "head"], "seed": 7}).json()
    other = client.post("/api/speak", json={**request, "life": ["blink", "head"], "seed": 8}).json()
    channels = lively["animation"]["channels"]
    assert channels[-5:] == ["eyeBlinkLeft", "eyeBlinkRight", "headYaw", "headPitch", "headRoll"]
    assert again["animation"] == lively["animation"]  # the same seed, the same frames
    assert other["animation"]["frames"] != lively["animation"]["frames"]
    # the speech is the cached one, the same audio, with the layers added
    assert lively["cached"] and lively["audio_url"] == plain["audio_url"]
    frames, speech = np.array(lively["animation"]["frames"]), np.array(plain["animation"]["frames"])
    np.testing.assert_array_equal(frames[:, :len(plain["animation"]["channels"])], speech)
    assert np.abs(frames[:, channels.index("headYaw")]).max() > 0
    assert frames[:, channels.index("eyeBlinkLeft")].max() > 0.5
    breathing = client.post("/api/speak", json={**request, "life": ["breath"]}).json()["animation"]
    assert breathing["channels"][-1] == "breath" and max(row[-1] for row in breathing["frames"]) > 0.4
    chat = client.post("/api/chat", json={"message": "Hi!", "language": "en", "life": ["gaze"], "seed": 1}).json()
    assert "eyeLookInLeft" in chat["speech"]["animation"]["channels"]


def test_the_expression_smiles_at_glad_words_and_frowns_at_sad_ones(client):
    """The expression layer reads the spoken text's mood: a glad one smiles on top of the speech's own
    smile, a sorry one frowns and raises the inner brows; the speech's other channels stay."""
    def spoken(text, life):
        answer = client.post("/api/speak", json={"text": text, "language": "en", "life": life, "seed": 3}).json()
        return dict(zip(answer["animation"]["channels"], np.array(answer["animation"]["frames"]).T))

    glad, plain = spoken("Thank you, that is wonderful!", ["expression"]), spoken("Thank you, that is wonderful!", [])
    assert (glad["mouthSmileLeft"] - plain["mouthSmileLeft"]).max() > 0.1 and glad["mouthFrownLeft"].max() == 0
    np.testing.assert_array_equal(glad["jawOpen"], plain["jawOpen"])
    sorry = spoken("I am so sorry, that is terrible news.", ["expression"])
    assert sorry["mouthFrownLeft"].max() > 0.05 and sorry["browInnerUp"].max() > 0.15


@pytest.mark.parametrize(("body", "words"), [
    ({"life": ["blink", "dance"]}, "life.1: Input should be 'blink', 'gaze', 'head', 'brows', 'breath' or 'expression'"),
    ({"life": "blink"}, "life"),
    ({"seed": -1}, "seed"),
])
def test_bad_layers_get_a_422(client, body, words):
    response = client.post("/api/speak", json={"text": "hello", **body})
    assert response.status_code == 422 and words in response.json()["detail"]
    chat = client.post("/api/chat", json={"message": "hello", **body})
    assert chat.status_code == 422 and words in chat.json()["detail"]


def test_the_layers_offered_are_the_motion_layers():
    from typing import get_args

    from vispeech.motion.life import LAYERS
    from vispeech.serve.schemas import Layer

    assert get_args(Layer) == LAYERS


def test_chat_answers_in_swedish_and_english(client):
    sv = client.post("/api/chat", json={"message": "Hej!", "language": "sv"}).json()
    assert sv["reply"] == GREETINGS["sv"] and sv["language"] == "sv"
    assert sv["speech"]["text"] == GREETINGS["sv"] and sv["speech"]["animation"]["n_frames"] > 10
    en = client.post("/api/chat", json={"message": "What is your name?", "language": "en", "speak": False}).json()
    assert en == {"reply": "My name is Vera.", "language": "en", "session": en["session"], "speech": None}
    other = client.post("/api/chat", json={"message": "Guten Tag!", "language": "de"})
    assert other.status_code == 400 and "chat bot speaks sv and en, not 'de'" in other.json()["detail"]
    # an English message on a Swedish page is answered in English, a Swedish one on an English page in Swedish
    asked = client.post("/api/chat", json={"message": "What is your name?", "language": "sv", "speak": True}).json()
    assert asked["reply"] == "My name is Vera." and asked["language"] == "en"
    assert asked["speech"]["animation"]["phones"]["language"] == "en"
    svar = client.post("/api/chat", json={"message": "Vad heter du?", "language": "en", "speak": False}).json()
    assert svar == {"reply": "Jag heter Vera.", "language": "sv", "session": svar["session"], "speech": None}
    unsure = client.post("/api/chat", json={"message": "ok", "language": "sv", "speak": False}).json()
    assert unsure["language"] == "sv"  # too short to tell: the page's language


def test_speak_in_any_language_espeak_speaks(client):
    german = client.post("/api/speak", json={"text": "Guten Tag, wie geht es dir?", "language": "de"}).json()
    phones = german["animation"]["phones"]
    assert phones["language"] == "ipa" and "ɡ" in [p["symbol"] for p in phones["phones"]]
    french = client.post("/api/speak", json={"text": "Bonjour mon ami.", "language": "fr"})  # fr is fr-fr's code
    assert french.status_code == 200 and french.json()["animation"]["n_frames"] > 10


def test_pages_static_files_and_the_2d_face(client, site):
    assert client.get("/").text == (site["static"] / "index.html").read_text()
    assert client.get("/player").text == (site["static"] / "player.html").read_text()
    assert client.get("/viewer").status_code == 200
    assert client.get("/static/style.css").text == "body{}"
    face = client.get("/static/face2d.js")
    assert face.status_code == 200 and face.content == FACE2D.read_bytes()
    assert "/api/speak" in client.get("/openapi.json").json()["paths"]



def test_api_docs_load_nothing_from_outside(client, site, tmp_path):
    docs = client.get("/docs")
    assert docs.status_code == 200 and "SwaggerUIBundle" in docs.text
    urls = re.findall(r"""(?:src|href|url)\s*[=:]\s*['"]([^'"]+)['"]""", docs.text)
    assert {"/openapi.json", "/static/swagger-ui/swagger-ui-bundle.js", "/static/swagger-ui/swagger-ui.css"} <= set(urls)
    assert not re.search(r"(?:https?:)?//", docs.text), "the docs page loads something from another host"
    for url in urls:
        if not url.startswith("data:"):
            assert client.get(url).status_code == 200, url
    assert '"validatorUrl": null' in docs.text  # no badge fetched from validator.swagger.io
    assert client.get("/redoc").status_code == 404  # ReDoc would come from a CDN
    with TestClient(create_app(ServeConfig(cache=":memory:", static_dir=tmp_path, head=False))) as bare:
        assert "npm run build" in bare.get("/docs").json()["detail"]  # not built: no blank page


def test_the_avatar_is_served_prepared_unless_asked_as_is(tmp_path):
    """A head with a tongue is served with its tongue morph targets and paint added (the same bytes
    `vispeech rig prepare` writes); --avatar-as-is, or a file that cannot be prepared (the site fixture's fake GLB,
    test_config), is served as it is."""
    from conftest import SHARED, require
    from vispeech.motion.rigging.head import prepare_head

    head = SHARED / "assets" / "ict_head.glb"
    require(head.is_file(), f"the ICT head ({head})")
    prepare_head(head, tmp_path / "ready.glb")
    with TestClient(create_app(ServeConfig(avatar=head, cache=":memory:"))) as served:
        body = served.get("/avatar.glb")
        assert body.status_code == 200 and body.headers["content-type"] == "model/gltf-binary"
        assert body.content == (tmp_path / "ready.glb").read_bytes() and b"tongueTipUp" in body.content
    with TestClient(create_app(ServeConfig(avatar=head, cache=":memory:", prepare_avatar=False))) as served:
        assert served.get("/avatar.glb").content == head.read_bytes()


def test_the_shipped_head_by_default_the_2d_face_on_request_and_no_built_web_app(tmp_path):
    from vispeech.motion.rigging.head import DEFAULT_HEAD, HEAD_CREDIT

    with TestClient(create_app(ServeConfig(cache=":memory:", head=False))) as flat:
        config = flat.get("/api/config").json()
        assert config["avatar_url"] is None and config["avatar_credit"] is None
        assert flat.get("/avatar.glb").status_code == 404
    with TestClient(create_app(ServeConfig(cache=tmp_path / "c.sqlite3", static_dir=tmp_path / "none"))) as bare:
        config = bare.get("/api/config").json()
        assert config["avatar_url"] == "/avatar.glb" and config["avatar_credit"] == HEAD_CREDIT
        head = bare.get("/avatar.glb")  # shipped prepared: served as it is
        assert head.status_code == 200 and head.content == DEFAULT_HEAD.read_bytes()
        page = bare.get("/")
        assert page.status_code == 404 and "npm run build" in page.json()["detail"]
        assert bare.get("/static/chat.js").status_code == 404
        assert bare.get("/static/face2d.js").status_code == 200
    with pytest.raises(VispeechError, match="avatar"):
        create_app(ServeConfig(avatar=tmp_path / "missing.glb", cache=":memory:"))
    with pytest.raises(VispeechError, match="not both"):
        create_app(ServeConfig(avatar=DEFAULT_HEAD, head=False, cache=":memory:"))


@pytest.mark.parametrize(("body", "status", "words"), [
    ({"text": "x" * 1001}, 422, "at most 1000"),
    ({"text": ""}, 422, "text"),
    ({"text": "   "}, 422, "text"),
    ({"text": "hi\u0000there"}, 422, "control characters"),
    ({"text": "hello", "language": "xx"}, 422, "unknown language 'xx'"),
    ({"text": "hello", "lang": "sv"}, 422, "unknown field 'lang'"),  # never silently ignored
    ({"text": "hello", "model": "no-such-model"}, 400, "unknown model"),
    ({"text": "hello", "model": "tdnn-beskow"}, 400, "unknown model"),
    ({"text": "hello", "rate": 9}, 422, "rate"),
    ({"text": ["hello"]}, 422, "text"),
    ({"language": "en"}, 422, "text: Field required"),
    ("hello", 422, "JSON object"),
])
def test_bad_speak_requests_get_a_clear_4xx(client, body, status, words):
    response = client.post("/api/speak", json=body)
    assert response.status_code == status
    assert words in response.json()["detail"]


def test_bad_json_and_oversize_bodies(client):
    bad = client.post("/api/speak", content=b'{"text": "hi"', headers={"content-type": "application/json"})
    assert bad.status_code == 422 and bad.json()["detail"] == "the body is not valid JSON"
    # JSON that Python's parser gives up on otherwise: an integer of 5000 digits, nesting past its
    # recursion limit, Latin-1 bytes
    for body in (b'{"text": "hi", "seed": ' + b"9" * 5000 + b"}", b"[" * 5000, '{"text": "hé"}'.encode("latin-1")):
        bad = client.post("/api/speak", content=body, headers={"content-type": "application/json"})
        assert bad.status_code == 422 and bad.json()["detail"] == "the body is not valid JSON", body[:20]
    nan = client.post("/api/speak", content=b'{"text": "hi", "rate": NaN}',
                      headers={"content-type": "application/json"})
    assert nan.status_code == 422
    surrogate = client.post("/api/speak", content=b'{"text": "Hello \\udcff world"}',  # a shell's undecodable byte
                            headers={"content-type": "application/json"})
    assert surrogate.status_code == 422 and "valid string" in surrogate.json()["detail"]
    huge = client.post("/api/speak", content=b"{" + b" " * 70_000 + b"}")
    assert huge.status_code == 413 and "too large" in huge.json()["detail"]
    chunked = client.post("/api/chat", content=(b" " * 8192 for _ in range(10)))  # no Content-Length
    assert chunked.status_code == 413


@pytest.mark.parametrize("path", [
    "/static/../../etc/passwd", "/static/%2e%2e/%2e%2e/etc/passwd", "/static/..%2f..%2fsecret.txt",
    "/static/%2e%2e/secret.txt", "/avatar.glb/../secret.txt", "/api/audio/..%2f..%2fsecret.txt.wav",
    "/api/audio/abc.wav", "/api/audio/" + "0" * 32 + ".wav",
])
def test_no_path_traversal(client, path):
    response = client.get(path)
    assert response.status_code == 404
    assert b"root:" not in response.content


def test_rate_limit_answers_429_and_the_server_keeps_serving(tmp_path):
    config = ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0.001, burst=2)
    with TestClient(create_app(config)) as limited:
        statuses = [limited.post("/api/chat", json={"message": "hi", "speak": False}).status_code for _ in range(3)]
        assert statuses == [200, 200, 429]
        refused = limited.post("/api/speak", json={"text": "hi"})
        assert refused.status_code == 429 and "rate limit" in refused.json()["detail"]
        assert int(refused.headers["retry-after"]) >= 1
        assert limited.get("/api/config").status_code == 200  # not limited


def test_token_bucket_refills_at_its_rate():
    now = [0.0]
    bucket = TokenBucket(rate=2.0, burst=3, clock=lambda: now[0])
    assert [bucket.take("a") for _ in range(4)] == [True, True, True, False]
    assert bucket.take("b")  # another client has its own bucket
    now[0] += 0.5  # one token back
    assert [bucket.take("a") for _ in range(2)] == [True, False]
    assert TokenBucket(rate=0, burst=1).take("a") and TokenBucket(rate=0, burst=1).take("a")


def test_fuzzed_requests_never_get_a_5xx(client):
    rng = random.Random(7)
    values = [None, True, 0, -1, 1e308, "", "x" * 1200, "en", "sv", "fr", [], {}, [1], {"a": 1},
              "\u0000", "😀", "!!!"]
    statuses = set()
    for _ in range(100):
        path = rng.choice(["/api/speak", "/api/chat"])
        body = {k: rng.choice(values) for k in rng.sample(["text", "message", "lang", "model", "rate", "speak"], 3)}
        if rng.random() < 0.2:
            content = json.dumps(body)[: rng.randrange(1, 30)].encode()
        else:
            content = json.dumps(body).encode()
        statuses.add(client.post(path, content=content, headers={"content-type": "application/json"}).status_code)
    assert max(statuses) < 500 and 422 in statuses
    assert client.get("/api/config").status_code == 200


def test_rule_bot():
    bot = RuleBot(clock=lambda: datetime(2024, 5, 1, 14, 5))
    assert bot.reply("Vad är klockan?", "sv") == "Klockan är 14:05."
    assert bot.reply("what time is it", "en") == "It is 14:05."
    assert bot.reply("Tack så mycket!", "sv") == "Varsågod!"
    assert bot.reply("Vad heter du?", "sv") == "Jag heter Vera."
    assert bot.reply("Can you help me?", "en").startswith("I am a talking avatar")
    assert bot.reply("Hello! Who are you?", "en") == "My name is Vera."  # the question wins over the greeting
    assert "did not understand" in bot.reply("quantum chromodynamics", "en")
    with pytest.raises(VispeechError):
        bot.reply("hej", "fr")


def test_utterance_cache_keys_and_eviction(tmp_path):
    cache = UtteranceCache(tmp_path / "c.sqlite3", max_entries=2)
    key = CacheKey("hi", "en", "en-us", 1.0, "baseline", "v1", 30.0, "arkit")
    ident = cache.entry_id
    assert len(ident(key)) == 32 and ident(key) == ident(CacheKey("hi", "en", "en-us", 1, "baseline", "v1", 30, "arkit"))
    fields = ("hi", "en", "en-us", 1.0, "baseline", "v1", 30.0, "arkit")
    changes = ("sv", "sv", 1.1, "ohman", "v2", 60.0)  # one field of the key after the text each
    variants = [CacheKey(*fields[:i + 1], change, *fields[i + 2:]) for i, change in enumerate(changes)]
    assert len({ident(key), *(ident(v) for v in variants)}) == 7
    for i, k in enumerate(variants[:3]):
        cache.put(k, b"wav%d" % i, "{}")
    assert len(cache) == 2 and cache.get(variants[0]) is None  # the least recently used went
    assert cache.audio(ident(variants[2])) == b"wav2"
    cache.close()
    (tmp_path / "bad.sqlite3").write_bytes(b"not a database at all" * 10)
    with pytest.raises(VispeechError, match="cannot open the cache"):
        UtteranceCache(tmp_path / "bad.sqlite3")


def test_serve_command_refuses_a_missing_avatar(tmp_path):
    from click.testing import CliRunner

    from vispeech.cli import main

    result = CliRunner().invoke(main, ["serve", "--avatar", str(tmp_path / "none.glb"), "--cache", str(tmp_path / "c")])
    assert result.exit_code == 2 and "avatar file not found" in result.output
    # a URL the browser cannot load was taken as a file name ("avatar file not found: ftp:/host/x.glb")
    result = CliRunner().invoke(main, ["serve", "--avatar", "ftp://host/x.glb", "--cache", str(tmp_path / "c")])
    assert result.exit_code == 2, result.output
    assert result.output.strip().endswith("--avatar takes a GLB or VRM file or an http(s) URL, not a ftp:// URL")
    assert len(result.output.strip().splitlines()) == 1


def test_answers_and_streams_come_in_the_output_scale(tmp_path, monkeypatch):
    """The server writes ARKit scale by default: its answers and stream frames are the model's
    tracks through the shipped calibration; scale="tracker" gives the model's own."""
    from vispeech.motion.rigging.calibration import load_scale
    from vispeech.motion.track import Track
    from vispeech.text_stream import SpeechTimeline

    # a stream's espeak-ng runs in its fast mode, whose samples differ a little from call to call
    # (frontends/espeak.py): the second stream places the clauses the first one voiced
    voiced_first, place = {}, SpeechTimeline.place
    monkeypatch.setattr(SpeechTimeline, "place", lambda self, v: place(self, voiced_first.setdefault(v.text, v)))
    arkit = load_scale("arkit")
    request = {"text": "Mamma made a map.", "language": "en", "model": "baseline"}
    answers, frames = {}, {}
    for scale in ("tracker", "arkit"):
        config = ServeConfig(cache=tmp_path / f"{scale}.sqlite3", rate_limit=0, stream_model="baseline", scale=scale)
        with TestClient(create_app(config)) as served:
            answers[scale] = served.post("/api/speak", json=request).json()["animation"]
            with served.websocket_connect("/api/stream") as ws:
                ws.send_json({"type": "text", "text": request["text"], "language": "en"})
                messages = []
                while not messages or messages[-1]["type"] != "end":
                    messages.append(ws.receive_json())
            frames[scale] = ([m for m in messages if m["type"] == "start"][0]["channels"],
                             [row for m in messages if m["type"] == "frames" for row in m["frames"]])
    raw = answers["tracker"]
    scaled = arkit.apply(Track(np.array(raw["frames"]), tuple(raw["channels"]), raw["fps"]))
    np.testing.assert_allclose(answers["arkit"]["frames"], scaled.values, atol=2e-6)  # both rounded to 1e-6
    jaw = raw["channels"].index("jawOpen")
    assert max(r[jaw] for r in answers["arkit"]["frames"]) > 1.3 * max(r[jaw] for r in raw["frames"])
    channels, rows = frames["tracker"]
    assert len(voiced_first) == 1  # the one clause, voiced once and placed on both streams
    np.testing.assert_allclose(frames["arkit"][1], arkit.apply(Track(np.array(rows), tuple(channels), 30.0)).values,
                               atol=2e-6)


def test_the_avatars_voice(tmp_path):
    """ServeConfig.voice speaks every answer with another espeak-ng voice; the cache keeps it apart."""
    request = {"text": "Hello there.", "language": "en", "model": "baseline"}
    audio = {}
    for voice in (None, "f3"):
        config = ServeConfig(cache=tmp_path / "c.sqlite3", rate_limit=0, voice=voice)
        with TestClient(create_app(config)) as served:
            answer = served.post("/api/speak", json=request).json()
            assert answer["cached"] is False  # the other voice's answer is not reused
            audio[voice] = served.get(answer["audio_url"]).content
    assert audio[None] != audio["f3"]
    with pytest.raises(VispeechError, match="unknown voice"):
        create_app(ServeConfig(cache=":memory:", voice="nobody"))


def test_an_answer_carries_the_files_it_asks_for(client, tmp_path):
    """formats: the animation's Live Link CSV, TalkingHead JSON, Oculus viseme CSV and Rhubarb
    cues, as `vispeech say` writes them, in the answer of /api/speak, /api/chat and /api/animate;
    the same cache entry answers with or without them."""
    from vispeech.motion.formats.registry import read_track

    request = {"text": "Bob will move five palms.", "model": "baseline"}
    plain = client.post("/api/speak", json=request).json()
    assert plain["files"] == {}
    asked = client.post("/api/speak", json={**request, "formats": ["livelink", "talkinghead", "oculus", "rhubarb"]})
    answer = asked.json()
    assert asked.status_code == 200 and answer["cached"] is True and answer["animation"] == plain["animation"]
    files = answer["files"]
    assert set(files) == {"livelink", "talkinghead", "oculus", "rhubarb"}
    frames = answer["animation"]["n_frames"]
    assert files["livelink"].startswith("Timecode,BlendshapeCount,") and len(files["livelink"].splitlines()) == frames + 1
    assert json.loads(files["talkinghead"])["name"] == "blendshapes"
    assert files["oculus"].splitlines()[0].startswith("time,sil,PP,FF,TH")
    cues = [line.split("\t") for line in files["rhubarb"].splitlines()]
    assert cues[0][1] == "X" and "A" in {shape for _, shape in cues}  # at rest, then closed on /b/ and /m/
    (tmp_path / "a.csv").write_text(files["livelink"])
    jaw = plain["animation"]["channels"].index("jawOpen")
    read_back = read_track(tmp_path / "a.csv")["jawOpen"]
    assert np.allclose(read_back, [row[jaw] for row in plain["animation"]["frames"]], atol=1e-5)
    chat = client.post("/api/chat", json={"message": "Hello", "formats": ["rhubarb"]}).json()
    assert set(chat["speech"]["files"]) == {"rhubarb"}
    wav = client.get(plain["audio_url"]).content
    uploaded = client.post("/api/animate?formats=oculus&formats=rhubarb", content=wav,
                           headers={"Content-Type": "audio/wav"})
    assert uploaded.status_code == 200, uploaded.text
    assert set(uploaded.json()["files"]) == {"oculus", "rhubarb"}
    refused = client.post("/api/speak", json={**request, "formats": ["gltf"]})
    assert refused.status_code == 422 and "formats" in refused.json()["detail"]


def test_options_per_request(client):
    """voice, fps and scale are the request's own, each part of the cache key; a misspelt or
    unknown option is a 422 naming it."""
    request = {"text": "Hello there.", "model": "baseline"}
    plain = client.post("/api/speak", json=request).json()
    asked = {"voice": {"voice": "f3"}, "fps": {"fps": 60}, "scale": {"scale": "tracker"}}
    answers = {name: client.post("/api/speak", json={**request, **option}).json() for name, option in asked.items()}
    assert all(answer["cached"] is False for answer in answers.values())  # none was the default's answer
    assert client.get(answers["voice"]["audio_url"]).content != client.get(plain["audio_url"]).content
    assert answers["fps"]["animation"]["fps"] == 60.0
    assert abs(answers["fps"]["animation"]["n_frames"] - 2 * plain["animation"]["n_frames"]) <= 1
    jaw = plain["animation"]["channels"].index("jawOpen")
    assert max(r[jaw] for r in answers["scale"]["animation"]["frames"]) < max(r[jaw] for r in plain["animation"]["frames"])
    assert client.post("/api/speak", json={**request, "voice": "f3"}).json()["cached"] is True
    spoken = client.post("/api/chat", json={"message": "Hello", "voice": "m2", "fps": 60}).json()["speech"]
    assert spoken["animation"]["fps"] == 60.0
    for bad, words in (({"vioce": "f3"}, "vioce"), ({"voice": "nobody"}, "unknown voice"),
                       ({"scale": "/etc/passwd"}, "scale"), ({"fps": 5000}, "fps")):
        refused = client.post("/api/speak", json={**request, **bad})
        assert refused.status_code == 422 and words in refused.json()["detail"], bad


def test_a_saved_model_folder_is_the_default_model(tmp_path):
    """The walkthrough's `vispeech serve --model my-tdnn` (a folder `train` wrote) was refused: the
    default model had to be a shipped name, though --stream-model took folders."""
    from click.testing import CliRunner

    from vispeech.cli import main
    from vispeech.models.registry import create_model

    create_model("cohen-massaro", theta={"default": 4.0, "vowel": 3.0, "silence": 12.0}).save(tmp_path / "my-model")
    config = ServeConfig(default_model=str(tmp_path / "my-model"), cache=":memory:", rate_limit=0)
    with TestClient(create_app(config)) as client:
        served = client.get("/api/config").json()
        assert served["default_model"] in served["models"] and served["default_model"] != "cohen-massaro"
        spoken = client.post("/api/speak", json={"text": "Hello there.", "language": "en"})
        assert spoken.status_code == 200, spoken.text
        shipped = client.post("/api/speak", json={"text": "Hello there.", "language": "en", "model": "cohen-massaro"})
        # the folder's model spoke (dominance of its own), not the family's defaults
        assert spoken.json()["animation"]["frames"] != shipped.json()["animation"]["frames"]
    result = CliRunner().invoke(main, ["serve", "--model", "grid-audio-cnn", "--cache", str(tmp_path / "c")])
    assert result.exit_code == 2 and "the default model must animate phones" in result.output
