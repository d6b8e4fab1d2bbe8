"""Avatars users bring, in Debian's Chromium driven by Playwright (as ``test_browser.py``): VRM 1.0
and 0.x models made from the shipped ICT head (``tests/vrm_heads.py``), one with only expression
presets in each version, one with ARKit morph targets ("perfect sync") and one with expressions
named after the ARKit shapes, say a sentence; the test reads their expression or morph weights on
the page. An ``--avatar`` URL is loaded by the browser from its own host. Skipped without
``/usr/bin/chromium`` or the ``playwright`` package, and failed then under ``CI=true``. Set
``VISPEECH_BROWSER_SCREENSHOTS=FOLDER`` to keep the screenshots
(docs/figures/avatar_*.png are these).
"""

from __future__ import annotations

import contextlib
import functools
import threading
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from conftest import require, require_module
from test_browser import CHROMIUM, OPEN_APERTURE, TEXT, _aperture, _browser_page, _centres, _serving
from test_browser import _screenshot as screenshot
from vrm_heads import vrm_head

from vispeech.motion.arkit import LIP_CLOSED

pytestmark = pytest.mark.browser

AVATARS = {"vrm1": ("1.0", False, False), "vrm0": ("0.x", False, False), "vrm0_perfect_sync": ("0.x", True, False),
           "vrm0_arkit_expressions": ("0.x", False, True)}
"""Each test avatar: VRM version, whether it has ARKit morph targets and whether ARKit-named expressions."""
DRIVES = {"vrm0_perfect_sync": "morphs", "vrm0_arkit_expressions": "arkit-expressions"}
"""How the page drives each avatar other than through its presets."""
VOWELS = ("aa", "ih", "ou", "ee", "oh")
MOUTH = ("jawOpen", "mouthClose", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
         "mouthUpperUpRight", "mouthFunnel", "mouthRollLower", "mouthRollUpper", "mouthPressLeft", "mouthPressRight")
"""The channels the lip aperture is made of."""
HOLD = """async ([t, vowels, channels]) => {
  const v = window.vispeech;
  v.seek(t);
  await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
  return {expressions: Object.fromEntries(vowels.map((e) => [e, v.expression(e)])),
          morphs: Object.fromEntries(channels.map((c) => [c, v.influences(c)]))};
}"""


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    """The test avatar of a name (:data:`AVATARS`), made once."""
    require(CHROMIUM.is_file(), f"Chromium ({CHROMIUM}: apt-get install chromium)")
    require_module("playwright.sync_api", "Playwright (the test extra)")
    folder = tmp_path_factory.mktemp("avatars")

    @functools.cache
    def made(name: str) -> Path:
        return vrm_head(folder / f"{name}.vrm", *AVATARS[name])

    return made


@pytest.mark.parametrize("name", AVATARS)
def test_a_brought_avatar_opens_its_mouth_on_vowels_and_closes_it_on_m(name, avatar_file, tmp_path):
    """Without ARKit morph targets a VRM's open vowels (aa, ee, oh) open as the lips part and no vowel
    shows at /m/; with them (perfect sync) the morph targets follow the track, as on the ICT head, and
    so do expressions named after the ARKit shapes."""
    drive = DRIVES.get(name, "vrm-presets")
    with (_serving(tmp_path / "cache.sqlite3", avatar=avatar_file(name), avatar_credit=None) as url,
          _browser_page(f"{url}/viewer?idle=0") as page):
        assert page.evaluate("() => window.vispeech.avatar.drive") == drive
        credit = page.evaluate("() => document.querySelector('#stage .credit').textContent")
        assert "by USC ICT, licence: https://opensource.org/license/mit" in credit  # the VRM's meta
        speech = page.evaluate("([text, lang]) => window.vispeech.speak(text, lang)", [TEXT, "en"])
        vowels, nasals = _centres(speech, ("AA", "AE")), _centres(speech, {"M"})
        assert len(vowels) >= 3 and len(nasals) >= 5
        for t in vowels + nasals:
            shown = page.evaluate(HOLD, [t, VOWELS + MOUTH, MOUTH])
            expressions = {e: shown["expressions"][e] for e in VOWELS}
            aperture = _aperture(shown["morphs"])
            if drive == "arkit-expressions":
                assert aperture == 0, (t, shown)  # no ARKit morph targets on the head: its expressions carry them
                aperture = _aperture({c: shown["expressions"][c] for c in MOUTH})
            if drive != "vrm-presets":
                assert set(expressions.values()) == {0}, (t, shown)  # the presets are left alone
                assert aperture >= OPEN_APERTURE if t in vowels else aperture <= LIP_CLOSED, (t, shown)
            else:
                assert aperture == 0, (t, shown)  # no ARKit morph targets on the head
                opened = expressions["aa"] + expressions["ee"] + expressions["oh"]
                assert opened >= 0.2 if t in vowels else max(expressions.values()) == 0, (t, expressions)
        page.evaluate(HOLD, [vowels[1], VOWELS, MOUTH])  # mid-sentence, "made a large"
        screenshot(page, tmp_path / f"avatar_{name}.png")
        assert page.errors == []


class _CrossOriginFiles(SimpleHTTPRequestHandler):
    """Files of a folder, to any origin (CORS), each GET's path noted in ``self.server.asked``."""

    def end_headers(self):
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def do_GET(self):
        self.server.asked.append(self.path)
        super().do_GET()

    def log_message(self, *args):
        pass


@contextlib.contextmanager
def _avatar_host(folder: Path) -> Iterator[tuple[str, list[str]]]:
    """``folder`` served on a free 127.0.0.1 port (another origin than the vispeech server's); its
    URL and the list of paths asked for."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_CrossOriginFiles, directory=str(folder)))
    server.asked = []
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", server.asked
    finally:
        server.shutdown()
        thread.join(10)
        server.server_close()


def test_an_avatar_url_is_loaded_by_the_player_from_its_host(avatar_file, tmp_path):
    """`vispeech serve --avatar URL`: the player page's browser fetches the VRM from its host, once; the
    vispeech server has no avatar file to serve."""
    vrm = avatar_file("vrm1")
    with _avatar_host(vrm.parent) as (host, asked):
        avatar = f"{host}/{vrm.name}"
        with (_serving(tmp_path / "cache.sqlite3", avatar=avatar, avatar_credit=None) as url,
              _browser_page(f"{url}/player?idle=0") as page):
            assert page.evaluate("() => window.vispeech.config.avatar_url") == avatar
            assert page.evaluate("() => window.vispeech.avatar.drive") == "vrm-presets"
            assert page.evaluate("() => fetch('/avatar.glb').then((r) => r.status)") == 404
            assert page.errors == []
    assert asked == [f"/{vrm.name}"]


def test_vrm_0_and_1_models_turn_their_heads_alike(avatar_file, tmp_path):
    """The same head as VRM 0.x (bones facing -Z) and 1.0, each loaded with ?avatar=URL, nodding and
    turning by the same angles through its neck bone, looks the same, pixel for pixel."""
    from test_browser import _rgb

    files = {version: avatar_file(name) for version, name in (("0.x", "vrm0"), ("1.0", "vrm1"))}
    turn = """async (angles) => {
      window.vispeech.avatar.setHeadRotation(...angles);
      await new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)));
    }"""
    shots = {}
    with (_avatar_host(files["1.0"].parent) as (host, _), _serving(tmp_path / "cache.sqlite3") as url,
          _browser_page(f"{url}/viewer?idle=0") as page):
        for version, file in files.items():
            page.goto(f"{url}/viewer?idle=0&avatar={host}/{file.name}")
            page.wait_for_function("window.vispeech && window.vispeech.ready", timeout=30_000)
            for pose, angles in (("rest", [0, 0, 0]), ("turned", [0.2, 0.3, 0.1])):
                page.evaluate(turn, angles)
                page.screenshot(path=str(tmp_path / f"{version}_{pose}.png"))
                shots[version, pose] = _rgb(tmp_path / f"{version}_{pose}.png")
        assert page.errors == []
    assert not (shots["1.0", "rest"] == shots["1.0", "turned"]).all()
    assert (shots["0.x", "turned"] == shots["1.0", "turned"]).all()
