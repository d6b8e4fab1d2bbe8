"""Stimuli for perceptual tests: speech degraded so that seeing the face matters, and faces
rendered to video side by side.

Beskow (2004) measured how much a talking head helps by playing its speech through a
noise-excited vocoder (Shannon et al. 1995) with three bands between 100 and 5000 Hz: the
words' rhythm and rough spectrum stay, their fine structure (voice pitch, formant detail) goes,
and listeners then lean on the lips. :func:`noise_vocode` does that:

1. the speech is split into ``bands`` bands with edges spaced evenly on a log scale from
   ``low`` to ``high`` Hz (100, 368, 1357 and 5000 Hz for three), each a 4th-order
   Butterworth band-pass run forwards and backwards (no phase shift);
2. each band's envelope: half-wave rectified, low-passed at ``envelope_cutoff`` Hz
   (160 Hz, Shannon's widest, keeps the syllables and their onsets);
3. white noise (seeded) through the same band-pass, times the envelope, scaled to the band's
   own RMS;
4. the bands summed and scaled to the input's RMS (clipped to [-1, 1]).

:func:`render_faces` renders tracks on the 2D face, or on a GLB head, to an MP4 with their sound,
several side by side in an order of the experimenter's choice (randomised per trial, as the
thesis placed its avatars), for a perceptual study.
"""

from __future__ import annotations

import base64
import itertools
import json
import os
from collections.abc import Iterable, Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

from vispeech.errors import VispeechError
from vispeech.motion.track import Track


def band_edges(bands: int = 3, low: float = 100.0, high: float = 5000.0) -> np.ndarray:
    """The ``bands + 1`` band edges (Hz), evenly spaced on a log scale from ``low`` to ``high``."""
    return np.geomspace(low, high, bands + 1)


def noise_vocode(
    samples: np.ndarray,
    sample_rate: int,
    *,
    bands: int = 3,
    low: float = 100.0,
    high: float = 5000.0,
    envelope_cutoff: float = 160.0,
    seed: int = 0,
) -> np.ndarray:
    """``samples`` (mono, float in [-1, 1]) through a noise-excited vocoder (see the module
    docstring); the same length, float32. Raises :class:`VispeechError` for bands beyond the
    Nyquist frequency or fewer than one band."""
    x = np.asarray(samples, dtype=np.float64)
    if bands < 1:
        raise VispeechError(f"a vocoder needs one band at least, got {bands}")
    if not 0 < low < high:
        raise VispeechError(
            f"the vocoder's lowest band edge must lie above 0 and below its highest, got {low:g}-{high:g} Hz"
        )
    if not high < sample_rate / 2:
        raise VispeechError(
            f"vocoder bands {low:g}-{high:g} Hz must lie below half the sample rate ({sample_rate / 2:g} Hz)"
        )
    if high / low < 2 ** (bands / 12):
        raise VispeechError(
            f"{bands} vocoder bands between {low:g} and {high:g} Hz are narrower than a semitone each: "
            "give fewer bands or a wider range"
        )
    if x.ndim != 1 or len(x) < 0.05 * sample_rate:
        raise VispeechError("the vocoder takes mono audio of 50 ms or more")
    rng = np.random.default_rng(seed)
    smooth = butter(4, envelope_cutoff, fs=sample_rate, output="sos")
    out = np.zeros_like(x)
    edges = band_edges(bands, low, high)
    for lo, hi in itertools.pairwise(edges):
        band = butter(4, [lo, hi], btype="band", fs=sample_rate, output="sos")
        speech = sosfiltfilt(band, x)
        envelope = np.maximum(sosfiltfilt(smooth, np.maximum(speech, 0.0)), 0.0)
        carrier = sosfiltfilt(band, rng.standard_normal(len(x)))
        voiced = carrier * envelope
        gain = np.sqrt(np.mean(speech**2) / max(np.mean(voiced**2), 1e-20))
        out += voiced * gain
    level = np.sqrt(np.mean(x**2) / max(float(np.mean(out**2)), 1e-20))
    return np.clip(out * level, -1.0, 1.0).astype(np.float32)


CHROMIUM_VARIABLE = "VISPEECH_CHROMIUM"
"""The environment variable naming the Chromium executable :func:`render_faces` drives
(default ``/usr/bin/chromium``, Debian's)."""

CHROMIUM_FLAGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
WEBGL_FLAGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader")
"""Added to :data:`CHROMIUM_FLAGS` for the 3D head: WebGL drawn on the CPU by SwiftShader."""
FACE_WIDTH = 320
"""Pixels across one face in a rendered stimulus (its height is 5/4 of it, the face's own box)."""
HEAD_BACKGROUND = "#3a3f46"
"""Behind the 3D head: the dark grey of the web app's stage."""
_BATCH = 25
"""Frames drawn per call into the page."""
_ORIGIN = "http://vispeech.stimuli"
"""Where the 3D head's page seems to live: Playwright answers every request to it (no server)."""

_PAGE = """<!doctype html><html><head><meta charset="utf-8"><style>body{margin:0;background:#fff}
canvas{display:block;float:left;width:%(w)dpx;height:%(h)dpx}</style></head><body>%(canvases)s
<script>%(face2d)s</script><script>
const faces = [...document.querySelectorAll("canvas.face")].map(
  (c) => new VispeechFace2D.Face2D(c, {background: "#ffffff"}));
const channels = %(channels)s;
const sheet = document.createElement("canvas");
sheet.width = %(w)d * faces.length; sheet.height = %(h)d;
window.frames_png = (rows, times) => rows.map((row, k) => {
  const ctx = sheet.getContext("2d");
  faces.forEach((face, i) => {
    face.setWeights(Object.fromEntries(channels[i].map((c, j) => [c, row[i][j]])), times[k]);
    ctx.drawImage(face.canvas, %(w)d * i, 0, %(w)d, %(h)d);
  });
  return sheet.toDataURL("image/png");
});
</script></body></html>"""

_HEAD_PAGE = """<!doctype html><html><head><meta charset="utf-8"><style>body{margin:0}</style>
<script type="module" src="/static/stimuli.js"></script></head><body></body></html>"""


def render_faces(
    tracks: Sequence[Track],
    path: str | os.PathLike,
    *,
    audio: np.ndarray | None = None,
    sample_rate: int | None = None,
    order: Sequence[int] | None = None,
    head: str | os.PathLike | None = None,
    prepare_head: bool = True,
) -> Path:
    """Render a face driven by each track, side by side in ``order`` (positions → track indices;
    default as given), with ``audio`` as the sound, to an MP4 (H.264 and AAC) at the first track's
    frame rate: a stimulus for a perceptual test, as the thesis showed its avatars. The face is the
    2D face (``vispeech/preview/face2d.js``, the one the preview page and the web app draw), or
    with ``head`` that GLB head (ARKit morph targets) as the web app shows it: made ready by
    :func:`vispeech.motion.rigging.head.prepared_head` (tongue targets, painted looks) unless
    ``prepare_head`` is false, drawn by the web build's ``stimuli.js`` (three.js), the head
    turned by the tracks' ``headPitch``/``headYaw``/``headRoll`` (degrees), no idle motion.

    Each face is :data:`FACE_WIDTH` pixels wide and 5/4 of that high. The tracks must share
    their frame rate; the video lasts as long as the longest (the others hold their last frame).
    Headless Chromium draws the frames (Playwright; the ``test`` extra), the 3D head through
    SwiftShader on the CPU: 7-11 heads a second on 2 cores (a 3-s clip of three heads at 25 fps
    in 25-36 s; the 2D faces in 2 s). Written atomically; raises
    :class:`VispeechError` for bad tracks or a head that is not a GLB with ARKit morph targets,
    before anything is written."""
    if not tracks:
        raise VispeechError("no track to render")
    fps = tracks[0].fps
    if any(abs(t.fps - fps) > 1e-6 for t in tracks):
        raise VispeechError("the tracks to render side by side must share their frame rate")
    order = list(range(len(tracks))) if order is None else list(order)
    if sorted(order) != list(range(len(tracks))):
        raise VispeechError(f"order {order} is not a permutation of the {len(tracks)} tracks")
    glb = None if head is None else _head_glb(Path(head), prepare_head)
    chromium = os.environ.get(CHROMIUM_VARIABLE, "/usr/bin/chromium")
    if not Path(chromium).is_file():
        raise VispeechError(f"rendering needs Chromium ({chromium}; set {CHROMIUM_VARIABLE})")
    from playwright.sync_api import Error as PlaywrightError
    from playwright.sync_api import sync_playwright

    width, height = FACE_WIDTH, FACE_WIDTH * 5 // 4
    n = max(t.n_frames for t in tracks)
    shown = [tracks[i] for i in order]
    channels = [list(t.channels) for t in shown]
    rows = [[t.values[min(k, t.n_frames - 1)].tolist() for t in shown] for k in range(n)]
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=chromium, headless=True, args=list(CHROMIUM_FLAGS) + list(WEBGL_FLAGS if glb else ())
        )
        try:
            page = browser.new_page(viewport={"width": width * len(shown), "height": height})
            if glb is None:
                _open_face_page(page, channels, width, height)
            else:
                _open_head_page(page, glb, channels, width, height)

            def draw(start: int) -> list[str]:
                """PNG data URLs of frames ``start`` to ``start + _BATCH``."""
                batch = rows[start : start + _BATCH]
                if glb is not None:
                    return page.evaluate("(rows) => window.vispeechStimuli.frames(rows)", batch)
                times = [k / fps for k in range(start, start + len(batch))]
                return page.evaluate("([rows, times]) => window.frames_png(rows, times)", [batch, times])

            pngs = (base64.b64decode(url.split(",", 1)[1]) for start in range(0, n, _BATCH) for url in draw(start))
            _write_mp4(pngs, path, fps=fps, size=(width * len(shown), height), audio=audio, sample_rate=sample_rate)
        except PlaywrightError as exc:
            raise VispeechError(f"the faces did not render: {str(exc).strip().splitlines()[0]}") from exc
        finally:
            browser.close()
    return Path(path)


def _head_glb(path: Path, prepare: bool) -> bytes:
    """The GLB head at ``path`` as the page gets it: prepared (see :func:`render_faces`) or as it is,
    once checked to carry ARKit morph targets."""
    from vispeech.motion.rigging.glb import read_primitives
    from vispeech.motion.rigging.head import prepared_head

    if not path.is_file():
        raise VispeechError(f"head file not found: {path}")
    if prepare:
        return prepared_head(path)[0]
    if not read_primitives(path):
        raise VispeechError(f"{path}: no mesh with ARKit morph targets")
    return path.read_bytes()


def _open_face_page(page, channels: list[list[str]], width: int, height: int) -> None:
    """Open the 2D faces' page in ``page``: one face (``face2d.js``) per entry of ``channels``."""
    from vispeech.preview.page import face2d_source

    page.set_content(
        _PAGE
        % {
            "w": width,
            "h": height,
            "canvases": '<canvas class="face"></canvas>' * len(channels),
            "face2d": face2d_source(),
            "channels": json.dumps(channels),
        }
    )


def _open_head_page(page, glb: bytes, channels: list[list[str]], width: int, height: int) -> None:
    """Open the web build's stimuli page in ``page`` with ``glb`` loaded once per slot; Playwright
    answers its requests: the page, the built scripts (``vispeech/serve/static``), the head."""
    from importlib.resources import files
    from urllib.parse import urlsplit

    static = Path(str(files("vispeech") / "serve" / "static")).resolve()
    if not (static / "stimuli.js").is_file():
        raise VispeechError(
            f"the web app's stimuli.js is not built in {static} (npm run build in web/, or reinstall vispeech)"
        )

    def answer(route) -> None:
        name = urlsplit(route.request.url).path
        if name == "/":
            route.fulfill(body=_HEAD_PAGE, content_type="text/html")
        elif name == "/head.glb":
            route.fulfill(body=glb, content_type="model/gltf-binary")
        else:
            file = (static / name.removeprefix("/static/")).resolve()
            if name.startswith("/static/") and file.is_relative_to(static) and file.is_file():
                route.fulfill(body=file.read_bytes(), content_type="text/javascript")
            else:
                route.fulfill(status=404, body="not found")

    page.route(f"{_ORIGIN}/**", answer)
    page.goto(f"{_ORIGIN}/")
    page.wait_for_function("() => window.vispeechStimuli !== undefined", timeout=30_000)
    page.evaluate(
        "([c, w, h, bg]) => window.vispeechStimuli.load('/head.glb', c, w, h, bg)",
        [channels, width, height, HEAD_BACKGROUND],
    )


def _write_mp4(
    pngs: Iterable[bytes],
    path: str | os.PathLike,
    *,
    fps: float,
    size: tuple[int, int],
    audio: np.ndarray | None,
    sample_rate: int | None,
) -> None:
    """Encode ``pngs`` (frames of ``size`` pixels) at ``fps`` with ``audio`` to an MP4 (H.264 and
    AAC) at ``path``, atomically."""
    import io

    import av
    from PIL import Image

    from vispeech.files import atomic_output_file

    with atomic_output_file(path) as tmp, av.open(str(tmp), "w", format="mp4") as container:
        video = container.add_stream(
            "libx264" if "libx264" in av.codecs_available else "mpeg4", rate=Fraction(fps).limit_denominator(1001)
        )
        video.width, video.height = size
        video.pix_fmt = "yuv420p"
        sound = None
        if audio is not None:
            assert sample_rate is not None  # audio comes with its sample rate
            sound = container.add_stream("aac", rate=int(sample_rate), layout="mono")
        for png in pngs:
            with Image.open(io.BytesIO(png)) as image:
                frame = av.VideoFrame.from_ndarray(np.asarray(image.convert("RGB")), format="rgb24")
            container.mux(video.encode(frame))
        container.mux(video.encode())
        if sound is not None:
            assert sample_rate is not None  # as above: there is sound only for audio, with its rate
            pcm = (np.clip(np.asarray(audio, dtype=np.float64), -1, 1) * 32767).astype(np.int16)
            for begin in range(0, len(pcm), 1024):
                chunk = av.AudioFrame.from_ndarray(pcm[None, begin : begin + 1024], format="s16", layout="mono")
                chunk.sample_rate = int(sample_rate)
                container.mux(sound.encode(chunk))
            container.mux(sound.encode())
