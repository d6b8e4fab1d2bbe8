"""Browser acceptance tests: the live talking head in Debian's Chromium, driven by Playwright.

The real server (``create_app`` under uvicorn, on a free loopback port) serves the viewer
with the ICT head; headless Chromium renders it with SwiftShader and plays the audio for
real (no virtual time); the microphone test is in ``test_browser_microphone.py``.
Skipped when ``/usr/bin/chromium``, the ``playwright`` package or the shared ICT head is
missing, and failed then under ``CI=true``; ``.ci/run``
installs the first two. Set ``VISPEECH_BROWSER_SCREENSHOTS=FOLDER`` to keep the screenshots
there as well.

Clock sync is measured at each draw of the page's performer (``Performer.tick``, wrapped by
the test): the pose's time (``clock()``) and frame (``frameIndex()``) it just computed are
compared with the audio heard at that moment, read from the audio output clock
(``AudioContext.getOutputTimestamp``) and mapped to utterance time through the
``AudioBufferSourceNode.start(when, offset)`` call that started the sound. SwiftShader paints
only a few frames a second here, so what is asserted is the time of the pose each draw puts
on screen, not how often the screen is painted.

How the open mouth looks (issue 26) is measured on screenshots of held vowels: the inside of
the mouth is found by drawing the head a second time flat (skin and lips in two colours, all
else black: black between the lips is where the mouth shows), its luma compared with the
lips' and its whitish pixels counted as teeth.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from conftest import SHARED, require, require_module
from vispeech.motion.arkit import LIP_CLOSED, TONGUE_CHANNELS, lip_aperture
from vispeech.motion.track import Track

pytestmark = pytest.mark.browser

CHROMIUM = Path("/usr/bin/chromium")
ICT_HEAD = SHARED / "assets" / "ict_head.glb"
CHROMIUM_FLAGS = [
    "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--autoplay-policy=no-user-gesture-required",
]
TEXT = "My mom made a large map of the farm."
"""1.96 s of speech: six /m/ and three /ɑ/ (AA) between them."""
OPEN_VOWELS = ("AA", "AE")
BILABIAL_NASAL = "M"
OPEN_APERTURE = 0.1
"""Lip aperture (0..1, ``lip_aperture``) the head must reach at an open vowel's centre: the default model
learned GRID's MediaPipe-tracked jaw, which opens less than iPhone ARKit capture (jawOpen about 0.25)."""


def _require_browser() -> None:
    require(CHROMIUM.is_file(), f"Chromium ({CHROMIUM}: apt-get install chromium)")
    require_module("playwright.sync_api", "Playwright (the test extra)")
    require(ICT_HEAD.is_file(), f"the ICT head ({ICT_HEAD}, in the shared data folder)")


@contextlib.contextmanager
def _serving(cache: Path, **settings) -> Iterator[str]:
    """The vispeech server with the ICT head (and ``settings``), in a thread on a free 127.0.0.1 port."""
    uvicorn = require_module("uvicorn", "uvicorn (the serve extra)")
    from vispeech.serve import ServeConfig, create_app

    head = {"avatar": ICT_HEAD, "avatar_credit": "3D head: ICT-FaceKit (USC ICT), MIT licence"}
    config = ServeConfig(cache=cache, rate_limit=0, **{**head, **settings})
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(create_app(config), log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started:
            assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
            time.sleep(0.05)
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()


@contextlib.contextmanager
def _browser_page(url: str, flags: tuple[str, ...] = ()) -> Iterator:
    """``url`` in headless Chromium, ready, with the page's errors in ``page.errors``."""
    from playwright import sync_api

    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                             args=[*CHROMIUM_FLAGS, *flags])
        try:
            page = browser.new_page(viewport={"width": 480, "height": 480})
            page.errors = []
            page.on("pageerror", lambda error: page.errors.append(str(error)))
            page.goto(url)
            page.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
            yield page
        finally:
            browser.close()


@pytest.fixture(scope="module")
def server_url(tmp_path_factory) -> Iterator[str]:
    """The vispeech server with the ICT head, in a thread on a free 127.0.0.1 port."""
    _require_browser()
    with _serving(tmp_path_factory.mktemp("browser") / "cache.sqlite3") as url:
        yield url


@pytest.fixture(scope="module")
def page(server_url):
    """The viewer (idle motion off) in headless Chromium, ready, with the page's errors in ``page.errors``."""
    with _browser_page(f"{server_url}/viewer?idle=0") as page:
        yield page


@pytest.fixture(scope="module")
def speech(page) -> dict:
    """The ``/api/speak`` answer for :data:`TEXT`, spoken through the page's ``speak``."""
    return page.evaluate("([text, lang]) => window.vispeech.speak(text, lang)", [TEXT, "en"])


@pytest.fixture(scope="module")
def screenshot_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("screens")


def _centres(speech: dict, symbols) -> list[float]:
    """Centres (seconds) of the spoken phones whose symbol is one of ``symbols``."""
    phones = speech["animation"]["phones"]["phones"]
    return [(p["start"] + p["end"]) / 2 for p in phones if p["symbol"] in symbols]


def _pose_at(page, t: float, channels) -> dict[str, float]:
    """Hold the pose at ``t`` s; the head mesh's morph influences of ``channels`` after the next paint."""
    return page.evaluate(
        """async ([t, channels]) => {
          const v = window.vispeech;
          v.seek(t);
          await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
          return Object.fromEntries(channels.map((c) => [c, v.influences(c)]));
        }""",
        [t, list(channels)],
    )


def _aperture(pose: dict[str, float]) -> float:
    """The project's lip aperture (0..1) of one pose."""
    return float(lip_aperture(Track(np.array([list(pose.values())]), tuple(pose), 30.0))[0])


def _expected_pose(animation: dict, t: float) -> dict[str, float]:
    """The animation's channels linearly interpolated at ``t`` s, clipped to 0..1 as the head shows them."""
    frames = np.asarray(animation["frames"])
    times = animation["start_time"] + np.arange(len(frames)) / animation["fps"]
    return {c: float(np.clip(np.interp(t, times, frames[:, i]), 0, 1)) for i, c in enumerate(animation["channels"])}


def _screenshot(page, path: Path) -> None:
    page.screenshot(path=str(path))
    keep = os.environ.get("VISPEECH_BROWSER_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(keep) / path.name)


def _rgb(path: Path) -> np.ndarray:
    """A screenshot's pixels (rows × columns × RGB, 0..1 as the screen shows them)."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"), dtype=float) / 255.0


def _mouth_interior(path: Path) -> np.ndarray:
    """Pixels of a screenshot where the mouth is open: in the lower middle of the face, dark (no
    channel over 0.45: skin and lips are paler) and deep red (green under 0.4 of red: the shaded
    tongue, gums and throat; nostrils and shadows are browner), in a run at least 5 pixels tall
    (the crease between closed lips is thinner)."""
    from scipy.ndimage import binary_erosion

    rgb = _rgb(path)
    height, width = rgb.shape[:2]
    where = np.zeros((height, width), dtype=bool)
    where[int(0.6 * height) : int(0.9 * height), int(0.3 * width) : int(0.7 * width)] = True
    dark = where & (rgb.max(axis=2) < 0.45) & (rgb[..., 1] < 0.4 * rgb[..., 0])
    return binary_erosion(dark, structure=np.ones((5, 1), dtype=bool))


def test_viewer_loads_the_ict_head_with_its_credit(page):
    head = page.evaluate(
        """() => {
          const v = window.vispeech;
          return {driven: v.avatar.headIndex ? v.avatar.headIndex.size : 0,
                  jawOpen: v.influences('jawOpen'),
                  canvas: !!document.querySelector('#stage canvas'),
                  credit: document.querySelector('#stage .credit')?.textContent ?? null,
                  audio: v.performer.context.state};
        }"""
    )
    assert head["driven"] == 55  # every ARKit shape (the ICT head's 51, tongueOut added) and the 3 tongue channels
    assert head["jawOpen"] == 0 and head["canvas"]
    assert head["credit"] == "3D head: ICT-FaceKit (USC ICT), MIT licence"
    assert head["audio"] == "running"  # autoplay allowed: the AudioContext's clock runs
    assert page.errors == []


def test_the_chat_page_shows_the_shipped_head_when_given_no_file(page, tmp_path):
    """`vispeech serve` with no head given: the chat page shows the 3D head the package ships,
    prepared (tongue targets), with its credit; --face-2d gives the 2D face."""
    from vispeech.motion.rigging.head import HEAD_CREDIT

    shown = """() => ({driven: window.vispeech.avatar.headIndex ? window.vispeech.avatar.headIndex.size : 0,
                       canvas: document.querySelector('#stage canvas')?.className ?? null,
                       credit: document.querySelector('#stage .credit')?.textContent ?? null})"""
    errors: list[str] = []
    for settings, expected in [({}, {"driven": 55, "canvas": "", "credit": HEAD_CREDIT}),
                               ({"head": False}, {"driven": 0, "canvas": "face2d", "credit": None})]:
        with _serving(tmp_path / f"{len(settings)}.sqlite3", avatar=None, avatar_credit=None, **settings) as url:
            chat = page.context.browser.new_page(viewport={"width": 480, "height": 480})  # one Playwright
            chat.on("pageerror", lambda error: errors.append(str(error)))
            try:
                chat.goto(url)
                chat.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
                assert chat.evaluate(shown) == expected
            finally:
                chat.close()
            assert errors == []


def test_mouth_is_open_at_open_vowels_and_closed_at_m(page, speech, screenshot_dir):
    animation = speech["animation"]
    channels = animation["channels"]
    vowels, nasals = _centres(speech, OPEN_VOWELS), _centres(speech, {BILABIAL_NASAL})
    assert len(vowels) >= 3 and len(nasals) >= 5, speech["animation"]["phones"]

    for t in vowels + nasals:
        pose = _pose_at(page, t, channels)
        expected = _expected_pose(animation, t)
        assert max(abs(pose[c] - expected[c]) for c in channels) < 1e-3, t  # the head shows the server's track
        if t in vowels:
            assert _aperture(pose) >= OPEN_APERTURE and pose["jawOpen"] > 0.15, (t, pose)
        else:
            assert _aperture(pose) <= LIP_CLOSED, (t, pose)

    # Screenshots: the first open vowel and the /m/ closing the syllable after it ("mom").
    vowel = vowels[0]
    nasal = min(t for t in nasals if t > vowel)
    interior = {}
    for name, t in (("vowel", vowel), ("m", nasal)):
        _pose_at(page, t, channels)
        path = screenshot_dir / f"ict_head_{name}_{t:.3f}s.png"
        _screenshot(page, path)
        interior[name] = _mouth_interior(path)
    # Open: tongue and gums show, low in the face and centred; closed: the lips hide them.
    rows, cols = np.nonzero(interior["vowel"])
    height, width = interior["vowel"].shape
    assert interior["vowel"].mean() > 0.001, "no mouth interior visible at the open vowel"
    assert 0.55 * height < rows.mean() < 0.85 * height and abs(cols.mean() - width / 2) < 0.1 * width
    assert interior["m"].sum() < 20, "mouth interior visible at /m/"


CLOCK_PROBE = """
async ([seconds]) => {
  // Instrument the page: note where the Web Audio API was told to start each sound, and
  // record, at every draw of the performer, the pose's time and frame beside the audio
  // output clock read at the same moment.
  const v = window.vispeech, performer = v.performer, context = performer.context;
  const starts = [];
  const start = AudioBufferSourceNode.prototype.start;
  AudioBufferSourceNode.prototype.start = function (when = 0, offset = 0, ...rest) {
    starts.push({when: Math.max(when, context.currentTime), offset});
    return start.call(this, when, offset, ...rest);
  };
  const draws = [];
  const tick = performer.tick;
  performer.tick = function (...args) {
    const before = performance.now();
    tick.apply(this, args);
    const out = context.getOutputTimestamp();
    draws.push({before, shown: v.clock(), frame: v.frameIndex(), audioTime: v.audioTime(),
                state: this.state, outContext: out.contextTime, outPerformance: out.performanceTime});
  };
  try {
    v.play(0);
    await new Promise((done) => setTimeout(done, seconds * 1000));
    return {starts, draws};
  } finally {
    performer.tick = tick;
    AudioBufferSourceNode.prototype.start = start;
  }
}
"""


def test_animation_clock_follows_the_audio_within_one_frame(page, speech):
    animation = speech["animation"]
    fps, start_time = animation["fps"], animation["start_time"]
    duration = speech["animation"]["phones"]["phones"][-1]["end"]
    probe = page.evaluate(CLOCK_PROBE, [duration + 0.3])
    assert len(probe["starts"]) == 1, probe["starts"]  # one sound: the utterance, from its start
    sound = probe["starts"][0]
    playing = [d for d in probe["draws"] if d["state"] == "playing" and 0 <= d["shown"] <= duration]
    for d in playing:
        # The audio heard when the pose was computed: the output clock's context time,
        # carried to that moment, mapped to utterance time by where the sound was started.
        heard_context = d["outContext"] + (d["before"] - d["outPerformance"]) / 1000
        d["audio"] = sound["offset"] + heard_context - sound["when"]
    assert len(playing) >= 5
    span = playing[-1]["audio"] - playing[0]["audio"]
    assert span > 0.6 * duration  # sampled across the utterance, in real time
    wall = (playing[-1]["before"] - playing[0]["before"]) / 1000
    assert abs(span - wall) <= 1 / fps  # the audio clock runs at real speed
    for d in playing:
        assert abs(d["shown"] - d["audioTime"]) <= 1 / fps, d
        assert abs(d["shown"] - d["audio"]) <= 1 / fps, d
        assert abs(start_time + d["frame"] / fps - d["audio"]) <= 1 / fps, d



def test_chat_page_offers_every_language_and_says_german(page, server_url):
    """The language menu lists espeak-ng's languages by name; with the rule bot, Send is off for
    German and Say speaks it, the head closing its lips on the /m/ of "Mama"."""
    chat = page.context.browser.new_page(viewport={"width": 480, "height": 480})  # the viewer's browser: one Playwright
    chat.errors = []
    chat.on("pageerror", lambda error: chat.errors.append(str(error)))
    try:
        chat.goto(f"{server_url}/")
        chat.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
        menu = chat.evaluate("() => [...document.querySelectorAll('#language option')].map((o) => [o.value, o.text])")
        assert menu[:2] == [["sv", "Svenska"], ["en", "English"]] and ["de", "German"] in menu and len(menu) > 100
        assert chat.evaluate("() => document.querySelector('#language').value") == "en"  # English, as elsewhere
        assert not chat.is_disabled("#send")
        chat.select_option("#language", "de")
        assert chat.is_disabled("#send") and "Say speaks German" in chat.get_attribute("#send", "title")
        speeches = []
        chat.on("response", lambda r: speeches.append(r.json()) if r.url.endswith("/api/speak") else None)
        chat.fill("#text", "Mama malt Blumen.")
        chat.click("#say")
        chat.wait_for_function("document.querySelector('#log .message') !== null", timeout=30_000)
        deadline = time.monotonic() + 30
        while not speeches and time.monotonic() < deadline:
            chat.wait_for_timeout(100)
        (speech,) = speeches
        phones = speech["animation"]["phones"]
        assert phones["language"] == "ipa"
        nasal = next((p["start"] + p["end"]) / 2 for p in phones["phones"] if p["symbol"] == "m")
        pose = _pose_at(chat, nasal, [c for c in speech["animation"]["channels"] if c != "tongueOut"])
        assert _aperture(pose) <= LIP_CLOSED, pose
        assert chat.is_disabled("#send") and chat.evaluate("document.querySelector('#status').hidden")
        assert chat.errors == []
    finally:
        chat.close()


def test_the_chat_page_speaks_a_chat_models_reply_as_it_streams(page, tmp_path):
    """With a chat model (a fake OpenAI-compatible server that streams), the chat page streams by
    default: the reply shows clause by clause, each sentence in its language, the avatar speaks it,
    and the next message goes on in the same session (the model hears the first exchange)."""
    from test_serve_chat import FakeChatModel, stream, tokens

    from vispeech.serve import OpenAIChatBot

    fake = FakeChatModel()
    try:
        fake.script = stream(tokens("Hello there! Hej, hur mår du?"))
        with _serving(tmp_path / "chat.sqlite3", bot=OpenAIChatBot(fake.url, "tiny-llm")) as url:
            chat = page.context.browser.new_page(viewport={"width": 480, "height": 480})  # one Playwright
            chat.errors = []
            chat.on("pageerror", lambda error: chat.errors.append(str(error)))
            try:
                chat.goto(f"{url}/?idle=0")
                chat.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
                assert chat.is_checked("#stream") and not chat.is_disabled("#send")
                replies = []
                chat.on("websocket", lambda ws: ws.on("framereceived", lambda frame: replies.append(frame)
                                                      if '"type":"reply"' in str(frame) else None))
                chat.fill("#text", "Say hello.")
                chat.press("#text", "Enter")
                chat.wait_for_function("document.querySelector('#log .bot')?.textContent === "
                                       "'Hello there! Hej, hur mår du?'", timeout=30_000)
                chat.wait_for_function("!document.querySelector('#send').disabled", timeout=30_000)
                assert [json.loads(r)["language"] for r in replies] == ["en", "sv"]
                fake.script = stream(tokens("Fine."))
                chat.fill("#text", "And you?")
                chat.press("#text", "Enter")
                chat.wait_for_function("document.querySelectorAll('#log .bot').length === 2 && "
                                       "!document.querySelector('#send').disabled", timeout=30_000)
                assert [m["content"] for m in fake.requests[-1][1]["messages"]] == [
                    "Say hello.", "Hello there! Hej, hur mår du?", "And you?"]
                assert chat.evaluate("document.querySelector('#status').hidden") and chat.errors == []
            finally:
                chat.close()
    finally:
        fake.close()


def test_the_rendered_lip_gap_is_the_calibrated_heads(page):
    """The head in the browser, posed from the ARKit-scaled tracked scores of grid_s1 test utterances,
    has the inner-lip gap over eye distance that the calibration computed, read from its morphed
    vertices (base + Σ influence · offset, through the mesh's world matrix)."""
    grid = SHARED / "data" / "grid_s1"
    require(grid.is_dir(), f"grid_s1 ({grid}, in the shared data folder)")
    from vispeech.corpus.grid import read_grid
    from vispeech.motion.rigging.calibration import HeadGeometry, load_scale

    head = HeadGeometry.from_glb(ICT_HEAD)
    arkit = load_scale("arkit")
    checked = closed = 0
    for utterance in list(read_grid(grid).split("test"))[:3]:
        track = arkit.apply(utterance.track)
        track = track.select([c for c in track.channels if not c.startswith("head")])  # lips, not the head's turn
        expected = head.gap(track)
        frames = list(range(0, track.n_frames, 7))
        rendered = page.evaluate(
            """async ([animation, frames, landmarks]) => {
              const v = window.vispeech;
              await v.playAnimation(animation, null, { autoplay: false });
              const mesh = v.avatar.head;
              const base = mesh.geometry.attributes.position;
              const offsets = mesh.geometry.morphAttributes.position;
              const at = (i) => {  // a vertex as shown now, in world space
                const p = [base.getX(i), base.getY(i), base.getZ(i)];
                mesh.morphTargetInfluences.forEach((w, t) => {
                  if (w) { p[0] += w * offsets[t].getX(i); p[1] += w * offsets[t].getY(i); p[2] += w * offsets[t].getZ(i); }
                });
                const e = mesh.matrixWorld.elements;
                return [0, 1, 2].map((r) => e[r] * p[0] + e[4 + r] * p[1] + e[8 + r] * p[2] + e[12 + r]);
              };
              const gaps = [];
              for (const k of frames) {
                v.seek(k / animation.fps);
                await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
                const eyes = Math.hypot(...[0, 1, 2].map((c) => at(landmarks.eye_left)[c] - at(landmarks.eye_right)[c]));
                gaps.push(Math.max(at(landmarks.upper_lip)[1] - at(landmarks.lower_lip)[1], 0) / eyes);
              }
              return gaps;
            }""",
            [{"format": "vispeech-animation", "version": 1, **track.to_dict()}, frames, head.landmarks],
        )
        np.testing.assert_allclose(rendered, expected[frames], atol=2e-3, err_msg=utterance.id)
        checked += len(frames)
        closed += int((expected[frames] < 0.02).sum())
    assert checked > 30 and closed > 0 and page.errors == []


TONGUE_TEXT = "Ten good cats thank Linda."
"""/t d n l/ (tip), /k g/ (body) and /θ/ (out), with open vowels between them."""
TONGUE_PROBE = """
async ([times]) => {
  // The tongue's own morph offsets, summed at the shown weights, at the vertex each tongue target
  // moves furthest (the tip for tongueTipUp and tongueOut, the dorsum for tongueBodyUp), in metres.
  const v = window.vispeech;
  let mesh = null;
  v.avatar.scene.traverse((o) => {
    if (o.isMesh && o.morphTargetDictionary && 'tongueTipUp' in o.morphTargetDictionary) {
      const a = o.geometry.morphAttributes.position[o.morphTargetDictionary.tongueTipUp];
      for (let i = 0; i < a.count; i++) if (a.getY(i) > 0) { mesh = o; break; }
    }
  });
  if (!mesh) return null;
  const offsets = mesh.geometry.morphAttributes.position, e = mesh.matrixWorld.elements;
  const world = (a, i) => [0, 1, 2].map((r) => e[r] * a.getX(i) + e[4 + r] * a.getY(i) + e[8 + r] * a.getZ(i));
  const furthest = (name, axis) => {
    const a = offsets[mesh.morphTargetDictionary[name]];
    let best = 0;
    for (let i = 0; i < a.count; i++) if (world(a, i)[axis] > world(a, best)[axis]) best = i;
    return best;
  };
  const names = ['tongueOut', 'tongueTipUp', 'tongueBodyUp', 'tongueBack'];
  const probes = {tip: [furthest('tongueTipUp', 1), 1], body: [furthest('tongueBodyUp', 1), 1],
                  out: [furthest('tongueOut', 2), 2]};
  const full = Object.fromEntries(Object.entries(probes).map(([k, [i, axis]]) =>
    [k, world(offsets[mesh.morphTargetDictionary[{tip: 'tongueTipUp', body: 'tongueBodyUp', out: 'tongueOut'}[k]]], i)[axis]]));
  const shown = [];
  for (const t of times) {
    v.seek(t);
    await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
    shown.push(Object.fromEntries(Object.entries(probes).map(([k, [i, axis]]) => [k, names.reduce((sum, name) => {
      const index = mesh.morphTargetDictionary[name];
      return sum + mesh.morphTargetInfluences[index] * world(offsets[index], i)[axis];
    }, 0)])));
  }
  return {full, shown};
}
"""


def test_the_head_shows_the_tongue(page):
    """The served head has tongue morph targets (vispeech rig prepare): the rendered tip rises at
    /t d n l/, the body at /k g/, the tip comes forward at /θ/, and none of them at open vowels."""
    speech = page.evaluate("([text, lang]) => window.vispeech.speak(text, lang)", [TONGUE_TEXT, "en"])
    groups = {"tip": {"T", "D", "N", "L"}, "body": {"K", "G"}, "out": {"TH"}, "vowel": set(OPEN_VOWELS)}
    centres = {name: _centres(speech, symbols) for name, symbols in groups.items()}
    assert all(centres.values()), centres
    times = [t for name in groups for t in centres[name]]
    probe = page.evaluate(TONGUE_PROBE, [times])
    assert probe is not None, "no tongue morph targets on the served head"
    full = probe["full"]
    assert full["tip"] > 0.008 and full["body"] > 0.008 and full["out"] > 0.008, full  # metres, the ICT head's mouth
    shown = dict(zip(times, probe["shown"]))
    for name, probe_name in (("tip", "tip"), ("body", "body"), ("out", "out")):
        reached = [shown[t][probe_name] / full[probe_name] for t in centres[name]]
        at_vowels = [shown[t][probe_name] / full[probe_name] for t in centres["vowel"]]
        assert min(reached) > 0.5, (name, reached)
        assert max(at_vowels) < 0.3, (name, at_vowels)
    assert page.errors == []


MOUTH_VOWELS = {"a": "AA", "i": "IY"}
"""The open vowels whose rendered mouth is measured, and their ARPAbet symbols."""
MASK_PASS = """
([lips, mouth, on]) => {
  // Draw the skin flat, green with its lips yellow (its vertex colours: lip weight, 1, 0), and
  // nothing else, on black (or all back as it was): what is black between the lips is where the
  // mouth's inside shows. Returns the box (page pixels) around the mouth hole's rim as shown now.
  const v = window.vispeech, avatar = v.avatar, head = avatar.head, colour = head.geometry.attributes.color;
  const saved = avatar.maskSaved;
  if (on && !saved) {
    const state = {material: head.material, colours: colour.array.slice(), background: avatar.container.style.background,
                   hidden: [], lights: []};
    avatar.scene.traverse((o) => {
      if ((o.isMesh && o !== head) || o.isDirectionalLight) { if (o.visible) state.hidden.push(o); o.visible = false; }
      if (o.isHemisphereLight) { state.lights.push([o, o.color.clone(), o.groundColor.clone(), o.intensity]);
                                 o.color.setRGB(1, 1, 1); o.groundColor.setRGB(1, 1, 1); o.intensity = Math.PI; }
    });
    const flat = head.material.clone();  // lit only by a white sky all round: its vertex colours exactly
    Object.assign(flat, {toneMapped: false, roughness: 1, metalness: 0, vertexColors: true, map: null});
    flat.color.setRGB(1, 1, 1);
    flat.emissive.setRGB(0, 0, 0);
    if ('sheen' in flat) flat.sheen = 0;
    head.material = flat;
    for (let i = 0; i < lips.length; i++) colour.setXYZ(i, lips[i], 1, 0);
    colour.needsUpdate = true;
    avatar.container.style.background = '#000';
    avatar.maskSaved = state;
  } else if (!on && saved) {
    saved.hidden.forEach((o) => { o.visible = true; });
    saved.lights.forEach(([o, sky, ground, intensity]) => { o.color.copy(sky); o.groundColor.copy(ground); o.intensity = intensity; });
    head.material = saved.material;
    colour.array.set(saved.colours);
    colour.needsUpdate = true;
    avatar.container.style.background = saved.background;
    avatar.maskSaved = null;
  }
  const base = head.geometry.attributes.position, offsets = head.geometry.morphAttributes.position;
  const rect = avatar.canvas.getBoundingClientRect(), e = head.matrixWorld.elements;
  const points = mouth.map((i) => {
    const p = [base.getX(i), base.getY(i), base.getZ(i)];
    head.morphTargetInfluences.forEach((w, t) => {
      if (w) { p[0] += w * offsets[t].getX(i); p[1] += w * offsets[t].getY(i); p[2] += w * offsets[t].getZ(i); }
    });
    const world = [0, 1, 2].map((r) => e[r] * p[0] + e[4 + r] * p[1] + e[8 + r] * p[2] + e[12 + r]);
    const ndc = avatar.camera.position.clone().set(...world).project(avatar.camera);
    return [rect.left + (ndc.x + 1) / 2 * rect.width, rect.top + (1 - ndc.y) / 2 * rect.height];
  });
  const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
  return [Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)];
}
"""


def _vowel_pose(symbol: str) -> dict[str, float]:
    """A vowel's pose held: the model's targets (``phone_targets``) and its tongue channels."""
    from vispeech.phonetics.features import phone_rows
    from vispeech.postprocess.tongue import tongue_targets
    from vispeech.targets.tables import phone_targets

    pose = {c: v for c, v in phone_targets(symbol, "en", 1).items() if v is not None}
    rows = phone_rows("en")
    tongue = tongue_targets(rows.features[rows.indices([symbol], [1])])[0]
    return {**pose, **dict(zip(TONGUE_CHANNELS, tongue.tolist()))}


def _hold(page, pose: dict[str, float]) -> None:
    """Hold ``pose`` on the head (as a one-frame animation) and wait for it to be drawn."""
    track = Track(np.array([list(pose.values())]), tuple(pose), 30.0)
    page.evaluate(
        """async (animation) => {
          const v = window.vispeech;
          await v.playAnimation(animation, null, { autoplay: false });
          v.seek(0);
          await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
        }""",
        {"format": "vispeech-animation", "version": 1, **track.to_dict()},
    )


def _mouth_measures(shown: Path, flat: Path, box: list[float]) -> dict[str, float]:
    """Luma of the mouth's inside over the lips', and its pixels, teeth and upper teeth, from a
    screenshot and its flat drawing (:data:`MASK_PASS`) near the mouth's ``box``."""
    rgb, mask = _rgb(shown), _rgb(flat)
    luma = rgb @ np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luma of the screen's sRGB
    near = np.zeros(luma.shape, dtype=bool)
    x0, y0, x1, y1 = box
    pad_x, pad_y = 0.3 * (x1 - x0), 0.3 * (y1 - y0)
    near[max(int(y0 - pad_y), 0) : int(y1 + pad_y) + 1, max(int(x0 - pad_x), 0) : int(x1 + pad_x) + 1] = True
    inside = near & (mask.max(axis=2) < 0.1)
    on_lips = near & (mask[..., 0] > 0.9) & (mask[..., 1] > 0.9) & (mask[..., 2] < 0.1)
    assert inside.sum() > 200 and on_lips.sum() > 200, (inside.sum(), on_lips.sum())
    chroma = rgb.max(axis=2) - rgb.min(axis=2)
    teeth = inside & (luma > 0.5 * luma[on_lips].mean()) & (chroma < 0.2 * rgb.max(axis=2))
    upper = teeth & (np.arange(luma.shape[0])[:, None] < np.nonzero(inside)[0].mean())
    return {"ratio": float(luma[inside].mean() / luma[on_lips].mean()), "inside": int(inside.sum()),
            "teeth": int(teeth.sum()), "upper teeth": int(upper.sum())}


def test_the_open_mouth_is_dark_inside_and_shows_its_teeth(page, screenshot_dir):
    """At /a/ and /i/ (the model's targets and tongue channels, held), where the mouth's inside
    shows between the lips (found by drawing the head again flat: skin green, lips yellow, the
    rest black), it is at /a/ on average under a third as bright as the lips (luma of the
    screen's sRGB), and at both teeth show in it: whitish pixels (luma over half the lips', chroma
    under a fifth of the brightest channel), at least 5 % of it, upper teeth 2 % (above its middle)."""
    from vispeech.motion.rigging.face import find_face
    from vispeech.motion.rigging.glb import read_primitives, skin_primitive
    from vispeech.motion.rigging.head_paint import lip_weights

    skin = skin_primitive(read_primitives(ICT_HEAD))
    face = find_face(skin)
    regions = [lip_weights(skin, face).tolist(), face.mouth.tolist()]
    drawn = "() => new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))"
    measured = {}
    for name, symbol in MOUTH_VOWELS.items():
        _hold(page, _vowel_pose(symbol))
        shown, flat = screenshot_dir / f"mouth_{name}.png", screenshot_dir / f"mouth_{name}_flat.png"
        _screenshot(page, shown)
        box = page.evaluate(MASK_PASS, [*regions, True])
        page.evaluate(drawn)
        _screenshot(page, flat)
        page.evaluate(MASK_PASS, [*regions, False])
        page.evaluate(drawn)
        measured[name] = _mouth_measures(shown, flat, box)
    assert measured["a"]["ratio"] < 1 / 3, measured
    for name, m in measured.items():
        assert m["teeth"] >= 0.05 * m["inside"] and m["upper teeth"] >= 0.02 * m["inside"], (name, measured)
    assert page.errors == []


def test_the_api_docs_render_offline(page, server_url):
    """/docs lists the API's operations with every request to another host refused (no CDN)."""
    docs = page.context.browser.new_page(viewport={"width": 1024, "height": 768})  # one Playwright
    docs.errors, foreign = [], []
    docs.on("pageerror", lambda error: docs.errors.append(str(error)))

    def offline(route):
        if route.request.url.startswith(server_url) or route.request.url.startswith("data:"):
            route.continue_()
        else:
            foreign.append(route.request.url)
            route.abort()

    docs.route("**/*", offline)
    try:
        docs.goto(f"{server_url}/docs")
        docs.wait_for_selector(".opblock", timeout=30_000)
        operations = docs.locator(".opblock-summary-path").all_inner_texts()
        assert {"/api/speak", "/api/config"} <= {text.strip().replace("\u200b", "") for text in operations}
        assert not foreign and not docs.errors, (foreign, docs.errors)
    finally:
        docs.close()


def test_the_viewer_loads_a_converted_glb_with_its_compression(page, tmp_path):
    """A glTF animation written onto the shipped head keeps its meshopt compression, the animation
    appended uncompressed: three.js (GLTFLoader with MeshoptDecoder) loads the file as it is."""
    from vispeech.motion.arkit import MORPH_NAMES
    from vispeech.motion.formats.gltf import write_gltf_animation
    from vispeech.motion.rigging.head import DEFAULT_HEAD

    track = Track(np.random.default_rng(3).uniform(0, 1, (60, len(MORPH_NAMES))), MORPH_NAMES, 30.0)
    write_gltf_animation(track, DEFAULT_HEAD, tmp_path / "take.glb")
    assert b"EXT_meshopt_compression" in (tmp_path / "take.glb").read_bytes()[:200_000]
    errors: list[str] = []
    with _serving(tmp_path / "cache.sqlite3", avatar=tmp_path / "take.glb", prepare_avatar=False) as url:
        viewer = page.context.browser.new_page(viewport={"width": 480, "height": 480})  # one Playwright
        viewer.on("pageerror", lambda error: errors.append(str(error)))
        try:
            viewer.goto(f"{url}/viewer?idle=0")
            viewer.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
            driven = viewer.evaluate("() => window.vispeech.avatar.headIndex ? window.vispeech.avatar.headIndex.size : 0")
            assert viewer.request.get(f"{url}/avatar.glb").body() == (tmp_path / "take.glb").read_bytes()
        finally:
            viewer.close()
    assert driven == 55 and errors == []


@contextlib.contextmanager
def _another_page(page, url: str) -> Iterator:
    """``url`` in a new tab of ``page``'s browser (a second Playwright would not run beside it)."""
    other = page.context.browser.new_page(viewport={"width": 480, "height": 480})
    try:
        other.errors = []
        other.on("pageerror", lambda error: other.errors.append(str(error)))
        other.goto(url)
        yield other
    finally:
        other.close()


def test_the_player_names_every_file_it_refuses(page, server_url, tmp_path):
    """Two animations opened at once, one bad: the player plays the good one and still says, in one
    line naming the file, what is wrong with the bad one (each file's error used to clear the one
    before); a value that is not a number is refused, not shown as a vanished head."""
    (tmp_path / "bad.csv").write_text("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,0.1\n"
                                      "00:00:00:01.000,1,abc\n")
    (tmp_path / "good.json").write_text(json.dumps({"format": "vispeech-animation", "version": 1, "fps": 30,
                                                    "channels": ["jawOpen"], "frames": [[0.1], [0.5], [0.2]]}))
    with _another_page(page, f"{server_url}/player?idle=0") as player:
        player.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
        player.set_input_files("#anim-file", [str(tmp_path / "bad.csv"), str(tmp_path / "good.json")])
        player.wait_for_function("!document.getElementById('status').hidden")
        assert player.inner_text("#status") == "bad.csv: line 3: a value is not a number"
        assert player.get_attribute("#scrub", "aria-label") == "time" and not player.errors


def test_the_player_fits_a_phone_screen(page, server_url):
    with _another_page(page, f"{server_url}/player?idle=0") as player:
        player.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
        player.set_viewport_size({"width": 375, "height": 667})
        assert player.evaluate("document.documentElement.scrollWidth") <= 375  # no sideways scrolling


def test_the_preview_seeks_to_a_changed_hash_even_with_a_time_in_its_query(page, tmp_path):
    """preview.md: `preview.html?t=0.62` opens paused there, and changing the hash of the open page
    seeks again (the query's time used to win over every later hash)."""
    from vispeech.pipeline import speak, write_outputs

    write_outputs(speak("Hello there, how are you?", "en"), tmp_path / "said")
    with _another_page(page, f"{(tmp_path / 'said' / 'preview.html').as_uri()}?t=0.62") as preview:
        preview.wait_for_function("document.getElementById('time').textContent.startsWith('0.62')")
        preview.evaluate("location.hash = '#t=1.5'")
        preview.wait_for_function("document.getElementById('time').textContent.startsWith('1.50')", timeout=5000)


@pytest.mark.parametrize(("name", "raw", "shown"), [
    ("NotFoundError", "Requested device not found",
     "no microphone found: connect one, or choose one in the browser's settings"),
    ("NotAllowedError", "Permission denied",
     "the microphone is blocked for this page: allow it in the browser's site settings"),
    ("AbortError", "Starting audio failed", "the microphone could not be opened (Starting audio failed)"),
])
def test_talk_without_a_microphone_says_what_to_do(page, server_url, name, raw, shown):
    """Talk on a machine with no microphone, or with it blocked, showed the browser's own words
    ("Requested device not found"); the chat page now says what the user can do."""
    with _another_page(page, f"{server_url}/?idle=0") as chat:
        chat.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
        chat.evaluate("([name, raw]) => { navigator.mediaDevices.getUserMedia = "
                      "() => Promise.reject(new DOMException(raw, name)); }", [name, raw])
        assert chat.is_visible("#mic")
        chat.click("#mic")
        chat.wait_for_function("document.querySelector('#mic').textContent === 'Talk' && "
                               "!document.querySelector('#mic').disabled && "
                               "document.getElementById('status').textContent !== ''", timeout=10_000)
        assert chat.inner_text("#status") == shown and not chat.errors
