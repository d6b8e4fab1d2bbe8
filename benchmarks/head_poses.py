"""The ICT head at an open vowel, /i/, /u/, /m/, /f/, /θ/, /t/, /k/ and at rest, in both output scales: a figure.

    python benchmarks/head_poses.py [--model grid-tdnn] [--out docs/figures/head_poses.png]

Speaks "Father sees you think my mom took the calm cat." through ``/api/speak`` of two servers with the
ICT head (prepared as ``vispeech serve --avatar`` serves it: tongue morph targets, painted looks;
``--scale tracker`` and ``--scale arkit``) in headless Chromium, holds the pose at the centre of
its /ɑ/ of "Father", its /i/ of "sees", its /u/ of "you", its /m/ of "my", its /f/, its /θ/, its
/t/ (tongue tip up), its /k/ (tongue body up) and the last frame (rest after speech), and puts the
screenshots in two labelled rows
(nose to chin). Also writes the whole head at rest (arkit scale) beside the figure as
``head_rest.png``. Prints the lip aperture of each pose. Needs Chromium, Playwright and Pillow
(the test extra).
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np

from languages_grid import CELL, FACE, ROOT, serving, viewer
from vispeech.motion.arkit import lip_aperture
from vispeech.motion.track import Track
from vispeech.pipeline import DEFAULT_MODEL

TEXT = "Father sees you think my mom took the calm cat."
POSES = (("open vowel /ɑ/", "AA"), ("/i/", "IY"), ("/u/", "UW"), ("/m/", "M"), ("/f/", "F"), ("/θ/", "TH"),
         ("/t/", "T"), ("/k/", "K"), ("rest", None))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default=DEFAULT_MODEL)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "head_poses.png")
    args = parser.parse_args()
    rows = []
    for scale in ("tracker", "arkit"):
        with serving(scale=scale) as url, viewer(f"{url}/viewer?idle=0") as page:
            speech = page.evaluate("([t, m]) => window.vispeech.speak(t, 'en', m)", [TEXT, args.model])
            animation = speech["animation"]
            track = Track(np.asarray(animation["frames"]), tuple(animation["channels"]), animation["fps"])
            aperture = lip_aperture(track)
            phones = animation["phones"]["phones"]
            shots = []
            for label, symbol in POSES:
                if symbol is None:
                    t = (track.n_frames - 1) / track.fps
                else:
                    phone = next(p for p in phones if p["symbol"] == symbol)
                    t = (phone["start"] + phone["end"]) / 2
                page.evaluate("(t) => window.vispeech.seek(t)", t)
                page.wait_for_timeout(300)
                shots.append((label, page.screenshot(), float(aperture[min(round(t * track.fps), track.n_frames - 1)])))
                if scale == "arkit" and symbol is None:
                    (args.out.parent / "head_rest.png").write_bytes(shots[-1][1])
                print(f"{scale:8} {label:16} lip aperture {shots[-1][2]:.3f}")
            rows.append((scale, shots))
    _figure(rows, args.out)
    print(f"wrote {args.out}")


def _figure(rows: list, out: Path) -> None:
    from PIL import Image, ImageDraw, ImageFont

    try:
        font = ImageFont.truetype("DejaVuSans.ttf", 14)
    except OSError:
        font = ImageFont.load_default()
    columns = len(rows[0][1])
    grid = Image.new("RGB", (columns * CELL, len(rows) * (CELL + 22)), "white")
    draw = ImageDraw.Draw(grid)
    for r, (scale, shots) in enumerate(rows):
        for c, (label, shot, aperture) in enumerate(shots):
            with Image.open(io.BytesIO(shot)) as image:
                w, h = image.size
                face = image.crop((int(FACE[0] * w), int(FACE[1] * h), int(FACE[2] * w), int(FACE[3] * h)))
                face = face.resize((CELL, CELL))
            x, y = c * CELL, r * (CELL + 22)
            grid.paste(face, (x, y))
            draw.text((x + 4, y + CELL + 3), f"{scale}: {label}  ({aperture:.2f})", fill="black", font=font)
    out.parent.mkdir(parents=True, exist_ok=True)
    grid.save(out)


if __name__ == "__main__":
    main()
