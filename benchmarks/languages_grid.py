"""The 20 test languages on the talking head: a screenshot grid and a table of figures.

    python benchmarks/languages_grid.py [--model grid-tdnn] [--out docs/figures/languages.png]

Serves vispeech with the ICT head (``../shared/assets/ict_head.glb``), speaks each sentence of
``tests/data/sentences_world.tsv`` through ``/api/speak`` in headless Chromium (the viewer
page, idle motion off), holds the pose at the frame where the jaw opens widest and takes a
screenshot; the screenshots make one grid, each labelled with its language, the phone at
that frame and the jawOpen there. Prints a Markdown table per language: phones, the share
known to the curated sets' features (all of them, for IPA), bilabials and how many of them
close, jaw peaks and how many fall inside vowels, the widest jawOpen and lip aperture.
Needs Chromium (``/usr/bin/chromium``), Playwright and Pillow (the test extra).
"""

from __future__ import annotations

import argparse
import socket
import threading
import time
from pathlib import Path

import numpy as np
from scipy.signal import find_peaks

from vispeech.evaluation.closures import is_bilabial, phone_frames
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import is_vowel
from vispeech.pipeline import DEFAULT_MODEL

ROOT = Path(__file__).resolve().parents[1]
SENTENCES = ROOT / "tests" / "data" / "sentences_world.tsv"
HEAD = ROOT.parent / "shared" / "assets" / "ict_head.glb"
CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--autoplay-policy=no-user-gesture-required"]
CELL = 240
FACE = (0.26, 0.47, 0.74, 0.95)
"""The box (shares of a screenshot's width and height: left, top, right, bottom) from the nose to the
chin, as the viewer frames the head."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default=DEFAULT_MODEL)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "languages.png")
    parser.add_argument("--columns", type=int, default=5)
    args = parser.parse_args()
    rows = [line.split("\t") for line in SENTENCES.read_text(encoding="utf-8").splitlines()
            if line.strip() and not line.startswith("#")]
    shots, figures = [], []
    with serving() as url, viewer(f"{url}/viewer?idle=0") as page:
        for lang, text in rows:
            speech = page.evaluate("([t, l, m]) => window.vispeech.speak(t, l, m)", [text, lang, args.model])
            animation = speech["animation"]
            track = Track(np.asarray(animation["frames"]), tuple(animation["channels"]), animation["fps"])
            widest = int(np.argmax(track["jawOpen"]))
            page.evaluate("(t) => window.vispeech.seek(t)", widest / track.fps)
            page.wait_for_timeout(300)
            shots.append(page.screenshot())
            figures.append(_figures(lang, animation, track, widest))
            print(f"{lang}: {figures[-1]['phone at widest']} jawOpen {figures[-1]['widest jawOpen']}", flush=True)
    _grid(shots, figures, args.columns, args.out)
    print(f"\nwrote {args.out}\n")
    keys = list(figures[0])
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for f in figures:
        print("| " + " | ".join(str(f[k]) for k in keys) + " |")


def _figures(lang: str, animation: dict, track: Track, widest: int) -> dict:
    phones = animation["phones"]
    language = phones["language"]
    spoken = [p for p in phones["phones"] if p["symbol"] not in ("sil", "sp")]
    aperture = lip_aperture(track)
    bilabials = [p for p in spoken if is_bilabial(p["symbol"], language)]
    closed = sum(aperture[phone_frames(p["start"], p["end"], track.fps, track.n_frames, pad=0)].min() <= LIP_CLOSED
                 for p in bilabials)
    peaks, _ = find_peaks(track["jawOpen"], prominence=0.02, height=0.05)
    vowels = [p for p in spoken if is_vowel(p["symbol"], language)]
    inside = sum(any(v["start"] - 1 / track.fps <= k / track.fps <= v["end"] + 1 / track.fps for v in vowels)
                 for k in peaks)
    at = next((p["symbol"] for p in phones["phones"] if p["start"] <= widest / track.fps < p["end"]), "?")
    return {"language": lang, "phones": language, "spoken phones": len(spoken), "bilabials closed":
            f"{closed}/{len(bilabials)}", "jaw peaks in vowels": f"{inside}/{len(peaks)}",
            "widest jawOpen": f"{track['jawOpen'][widest]:.2f}", "phone at widest": at,
            "widest aperture": f"{aperture.max():.2f}"}


def _grid(shots: list[bytes], figures: list[dict], columns: int, out: Path) -> None:
    import io

    from PIL import Image, ImageDraw, ImageFont

    try:  # a font with the IPA letters (Debian's fonts-dejavu-core, which Chromium pulls in)
        font = ImageFont.truetype("DejaVuSans.ttf", 14)
    except OSError:
        font = ImageFont.load_default()
    rows = -(-len(shots) // columns)
    grid = Image.new("RGB", (columns * CELL, rows * (CELL + 22)), "white")
    draw = ImageDraw.Draw(grid)
    for i, (shot, figure) in enumerate(zip(shots, figures)):
        with Image.open(io.BytesIO(shot)) as image:  # nose to chin
            w, h = image.size
            face = image.crop((int(FACE[0] * w), int(FACE[1] * h), int(FACE[2] * w), int(FACE[3] * h)))
            face = face.resize((CELL, CELL))
        x, y = (i % columns) * CELL, (i // columns) * (CELL + 22)
        grid.paste(face, (x, y))
        draw.text((x + 4, y + CELL + 3), f"{figure['language']}  /{figure['phone at widest']}/  "
                  f"jawOpen {figure['widest jawOpen']}", fill="black", font=font)
    out.parent.mkdir(parents=True, exist_ok=True)
    grid.save(out)


class serving:
    """vispeech serve with the ICT head (in output ``scale``), in a thread on a free 127.0.0.1 port."""

    def __init__(self, scale: str = "arkit") -> None:
        self.scale = scale

    def __enter__(self) -> str:
        import uvicorn

        from vispeech.serve import ServeConfig, create_app

        config = ServeConfig(avatar=HEAD, avatar_credit="3D head: ICT-FaceKit (USC ICT), MIT licence",
                             cache=":memory:", rate_limit=0, scale=self.scale)
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.server = uvicorn.Server(uvicorn.Config(create_app(config), log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 60
        while not self.server.started:
            if time.monotonic() > deadline:
                raise SystemExit("the server did not start")
            time.sleep(0.05)
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}"

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(10)
        self.sock.close()


class viewer:
    """The viewer page in headless Chromium, ready."""

    def __init__(self, url: str) -> None:
        self.url = url

    def __enter__(self):
        from playwright import sync_api

        self.playwright = sync_api.sync_playwright().start()
        self.browser = self.playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=FLAGS)
        page = self.browser.new_page(viewport={"width": 600, "height": 600})
        page.goto(self.url)
        page.wait_for_function("window.vispeech && window.vispeech.ready", timeout=60_000)
        return page

    def __exit__(self, *exc) -> None:
        self.browser.close()
        self.playwright.stop()


if __name__ == "__main__":
    main()
