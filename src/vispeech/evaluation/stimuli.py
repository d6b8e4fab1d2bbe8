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

:func:`render_faces` renders tracks on the 2D face to an MP4 with their sound, several side by
side in an order of the experimenter's choice (randomised per trial, as the thesis placed its
avatars), for a perceptual study.
"""

from __future__ import annotations

import base64
import os
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

from vispeech.errors import VispeechError
from vispeech.motion.track import Track


def band_edges(bands: int = 3, low: float = 100.0, high: float = 5000.0) -> np.ndarray:
    """The ``bands + 1`` band edges (Hz), evenly spaced on a log scale from ``low`` to ``high``."""
    return np.geomspace(low, high, bands + 1)


def noise_vocode(samples: np.ndarray, sample_rate: int, *, bands: int = 3, low: float = 100.0,
                 high: float = 5000.0, envelope_cutoff: float = 160.0, seed: int = 0) -> np.ndarray:
    """``samples`` (mono, float in [-1, 1]) through a noise-excited vocoder (see the module
    docstring); the same length, float32. Raises :class:`VispeechError` for bands beyond the
    Nyquist frequency or fewer than one band."""
    x = np.asarray(samples, dtype=np.float64)
    if bands < 1:
        raise VispeechError(f"a vocoder needs one band at least, got {bands}")
    if not 0 < low < high < sample_rate / 2:
        raise VispeechError(f"vocoder bands {low:g}-{high:g} Hz must lie below half the sample rate "
                            f"({sample_rate / 2:g} Hz)")
    if x.ndim != 1 or len(x) < 0.05 * sample_rate:
        raise VispeechError("the vocoder takes mono audio of 50 ms or more")
    rng = np.random.default_rng(seed)
    smooth = butter(4, envelope_cutoff, fs=sample_rate, output="sos")
    out = np.zeros_like(x)
    edges = band_edges(bands, low, high)
    for lo, hi in zip(edges[:-1], edges[1:]):
        band = butter(4, [lo, hi], btype="band", fs=sample_rate, output="sos")
        speech = sosfiltfilt(band, x)
        envelope = np.maximum(sosfiltfilt(smooth, np.maximum(speech, 0.0)), 0.0)
        carrier = sosfiltfilt(band, rng.standard_normal(len(x)))
        voiced = carrier * envelope
        gain = np.sqrt(np.mean(speech ** 2) / max(np.mean(voiced ** 2), 1e-20))
        out += voiced * gain
    level = np.sqrt(np.mean(x ** 2) / max(np.mean(out ** 2), 1e-20))
    return np.clip(out * level, -1.0, 1.0).astype(np.float32)


CHROMIUM_VARIABLE = "VISPEECH_CHROMIUM"
"""The environment variable naming the Chromium executable :func:`render_faces` drives
(default ``/usr/bin/chromium``, Debian's)."""

CHROMIUM_FLAGS = ("--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync")
FACE_WIDTH = 320
"""Pixels across one face in a rendered stimulus (its height is 5/4 of it, the face's own box)."""

_PAGE = """<!doctype html><html><head><meta charset="utf-8"><style>body{margin:0;background:#fff}
canvas{display:block;float:left;width:%(w)dpx;height:%(h)dpx}</style></head><body>%(canvases)s
<script>%(face2d)s</script><script>
const faces = [...document.querySelectorAll("canvas.face")].map(
  (c) => new VispeechFace2D.Face2D(c, {background: "#ffffff"}));
const sheet = document.createElement("canvas");
sheet.width = %(w)d * faces.length; sheet.height = %(h)d;
window.frames_png = (rows, times) => rows.map((weights, k) => {
  const ctx = sheet.getContext("2d");
  faces.forEach((face, i) => { face.setWeights(weights[i], times[k]); ctx.drawImage(face.canvas, %(w)d * i, 0, %(w)d, %(h)d); });
  return sheet.toDataURL("image/png");
});
</script></body></html>"""


def render_faces(tracks: Sequence[Track], path: str | os.PathLike, *, audio: np.ndarray | None = None,
                 sample_rate: int | None = None, order: Sequence[int] | None = None) -> Path:
    """Render the 2D face (``vispeech/preview/face2d.js``, the one the preview page and the web app
    draw) driven by each track, side by side in ``order`` (positions → track indices; default
    as given), with ``audio`` as the sound, to an MP4 (H.264 and AAC) at the first track's frame
    rate: a stimulus for a perceptual test, as the thesis showed its avatars. The tracks must
    share their frame rate; the video lasts as long as the longest (the others hold their last
    frame). Headless Chromium draws the frames (Playwright; the ``test`` extra). Written atomically."""
    import io

    import av
    from PIL import Image
    from playwright.sync_api import sync_playwright

    from vispeech.files import atomic_output_file
    from vispeech.preview.page import face2d_source

    if not tracks:
        raise VispeechError("no track to render")
    fps = tracks[0].fps
    if any(abs(t.fps - fps) > 1e-6 for t in tracks):
        raise VispeechError("the tracks to render side by side must share their frame rate")
    order = list(range(len(tracks))) if order is None else list(order)
    if sorted(order) != list(range(len(tracks))):
        raise VispeechError(f"order {order} is not a permutation of the {len(tracks)} tracks")
    chromium = os.environ.get(CHROMIUM_VARIABLE, "/usr/bin/chromium")
    if not Path(chromium).is_file():
        raise VispeechError(f"rendering needs Chromium ({chromium}; set {CHROMIUM_VARIABLE})")
    width, height = FACE_WIDTH, FACE_WIDTH * 5 // 4
    n = max(t.n_frames for t in tracks)
    shown = [tracks[i] for i in order]
    rows = [[{c: float(v) for c, v in zip(t.channels, t.values[min(k, t.n_frames - 1)])} for t in shown]
            for k in range(n)]
    canvases = "".join('<canvas class="face"></canvas>' for _ in shown)
    page_html = _PAGE % {"w": width, "h": height, "canvases": canvases, "face2d": face2d_source()}
    images = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, headless=True, args=list(CHROMIUM_FLAGS))
        try:
            page = browser.new_page(viewport={"width": width * len(shown), "height": height})
            page.set_content(page_html)
            for start in range(0, n, 50):
                urls = page.evaluate("([rows, times]) => window.frames_png(rows, times)",
                                     [rows[start:start + 50], [k / fps for k in range(start, min(n, start + 50))]])
                images += [base64.b64decode(url.split(",", 1)[1]) for url in urls]
        finally:
            browser.close()
    with atomic_output_file(path) as tmp:
        with av.open(str(tmp), "w", format="mp4") as container:
            video = container.add_stream("libx264" if "libx264" in av.codecs_available else "mpeg4",
                                         rate=Fraction(fps).limit_denominator(1001))
            video.width, video.height, video.pix_fmt = width * len(shown), height, "yuv420p"
            sound = None
            if audio is not None:
                sound = container.add_stream("aac", rate=int(sample_rate), layout="mono")
            for png in images:
                with Image.open(io.BytesIO(png)) as image:
                    frame = av.VideoFrame.from_ndarray(np.asarray(image.convert("RGB")), format="rgb24")
                container.mux(video.encode(frame))
            container.mux(video.encode())
            if sound is not None:
                pcm = (np.clip(np.asarray(audio, dtype=np.float64), -1, 1) * 32767).astype(np.int16)
                for begin in range(0, len(pcm), 1024):
                    chunk = av.AudioFrame.from_ndarray(pcm[None, begin:begin + 1024], format="s16", layout="mono")
                    chunk.sample_rate = int(sample_rate)
                    container.mux(sound.encode(chunk))
                container.mux(sound.encode())
    return Path(path)
