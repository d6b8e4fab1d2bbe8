"""The 2D face script's mouth geometry and drawing, run in Node (skipped where Node is missing, failed under CI)."""

import json
import re
import shutil
import subprocess
from importlib import resources

import pytest
from conftest import require

NODE = shutil.which("node")


@pytest.fixture(autouse=True)
def _needs_node():
    require(NODE is not None, "Node.js (node on PATH)")


# Loads face2d.js as a browser would (a global scope, no modules), evaluates mouthShape on the
# cases read from stdin and draws each case on a fake canvas that rejects what a browser rejects.
# Each fill in a plain colour is kept as [colour, x0, y0, x1, y1]: the box around its path's
# points (curve control points included, ellipses without rotation), in drawing units.
HARNESS = r"""
const fs = require("fs");
const vm = require("vm");
const [script, cases] = JSON.parse(fs.readFileSync(0, "utf8"));
const calls = [];
const fills = [];
let points = [];
function trace(name, args, style) {
  if (name === "beginPath") points = [];
  else if (["moveTo", "lineTo", "quadraticCurveTo", "bezierCurveTo"].includes(name))
    for (let k = 0; k + 1 < args.length; k += 2) points.push([args[k], args[k + 1]]);
  else if (name === "ellipse" || name === "arc") {
    const [x, y, rx] = args, ry = name === "ellipse" ? args[3] : rx;
    points.push([x - rx, y - ry], [x + rx, y + ry]);
  } else if (name === "rect") points.push([args[0], args[1]], [args[0] + args[2], args[1] + args[3]]);
  else if (name === "fillRect" && typeof style === "string")
    fills.push([style, args[0], args[1], args[0] + args[2], args[1] + args[3]]);
  else if (name === "fill" && typeof style === "string" && points.length) {
    const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
    fills.push([style, Math.min(...xs), Math.min(...ys), Math.max(...xs), Math.max(...ys)]);
  }
}
function context2d() {
  const target = {};
  return new Proxy(target, {
    get(obj, name) {
      if (name in obj) return obj[name];
      if (name.startsWith("create")) return () => ({ addColorStop() {} });
      return (...args) => {
        if (args.some((a) => typeof a === "number" && !Number.isFinite(a))) throw new Error(`${name}: non-finite argument`);
        if ((name === "arc" && args[2] < 0) || (name === "ellipse" && (args[2] < 0 || args[3] < 0)))
          throw new Error(`${name}: negative radius`);
        calls.push(name);
        trace(name, args, obj.fillStyle);
      };
    },
    set(obj, name, value) { obj[name] = value; return true; },
  });
}
const canvas = { width: 400, height: 500, clientWidth: 200, clientHeight: 250, getContext: () => context2d() };
const sandbox = { performance: { now: () => 0 }, devicePixelRatio: 2 };
sandbox.window = sandbox;
vm.createContext(sandbox);
vm.runInContext(script, sandbox);
const lib = sandbox.VispeechFace2D;
const face = new lib.Face2D(canvas);
const out = {};
for (const [name, weights] of Object.entries(cases)) {
  calls.length = 0;
  fills.length = 0;
  face.setWeights(weights, 0.5);
  out[name] = { shape: lib.mouthShape(weights), drawCalls: calls.length, fills: fills.slice() };
}
out.canvas = [canvas.width, canvas.height];
out.channels = lib.CHANNELS;
process.stdout.write(JSON.stringify(out));
"""

CASES = {
    "rest": {},
    "m": {"jawOpen": 0.1, "mouthClose": 0.1},
    "m_wide_jaw": {"jawOpen": 0.4, "mouthClose": 0.4, "mouthFunnel": 0.3, "mouthLowerDownLeft": 0.5},
    "press": {"mouthPressLeft": 1, "mouthPressRight": 1, "mouthUpperUpLeft": 0.4},
    "a": {"jawOpen": 0.5},
    "a_half_closed": {"jawOpen": 0.5, "mouthClose": 0.25},
    "u": {"jawOpen": 0.2, "mouthPucker": 0.9},
    "i": {"jawOpen": 0.15, "mouthSmileLeft": 0.8, "mouthSmileRight": 0.8},
    "smile_left": {"mouthSmileLeft": 1},
    "f": {"jawOpen": 0.08, "mouthRollLower": 0.9},
    "upper_up": {"mouthUpperUpLeft": 1, "mouthUpperUpRight": 1},
    "lower_down": {"mouthLowerDownLeft": 1, "mouthLowerDownRight": 1},
    "tongue_out": {"jawOpen": 0.3, "tongueOut": 1},
    "tongue_out_sealed": {"jawOpen": 0.3, "mouthClose": 0.3, "tongueOut": 1},
    "t": {"jawOpen": 0.15, "tongueTipUp": 1},
    "jaw_only": {"jawOpen": 0.15},
    "tongue_rest": {"jawOpen": 0.2},
    "tip_up": {"jawOpen": 0.2, "tongueTipUp": 1},
    "body_up": {"jawOpen": 0.2, "tongueBodyUp": 1},
    "tongue_back": {"jawOpen": 0.2, "tongueBack": 1},
    "tongue_sealed": {"jawOpen": 0.2, "mouthClose": 0.2, "tongueTipUp": 1, "tongueBodyUp": 1, "tongueBack": 1},
    "everything": {"jawOpen": 1, "jawForward": 1, "jawLeft": 1, "mouthFunnel": 1, "mouthPucker": 1,
                   "mouthStretchLeft": 1, "eyeBlinkLeft": 1, "cheekPuff": 1, "tongueOut": 1},
    "junk": {"jawOpen": "wide", "mouthClose": None, "mouthPucker": -3, "mouthSmileLeft": 7},
}


def script():
    return resources.files("vispeech.preview").joinpath("face2d.js").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def run():
    done = subprocess.run([NODE, "-e", HARNESS], input=json.dumps([script(), CASES]), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def width(shape):
    return shape["x"][-1] - shape["x"][0]


def mid(values):
    return values[len(values) // 2]


def test_channels_are_pythons_morph_names(run):
    from vispeech.motion.arkit import MORPH_NAMES

    undrawn = {"eyeSquintLeft", "eyeSquintRight", "cheekSquintLeft", "cheekSquintRight"}  # no lower lids or cheeks
    assert len(run["channels"]) == len(set(run["channels"]))
    assert set(run["channels"]) == set(MORPH_NAMES) - undrawn


def test_every_case_draws(run):
    assert run["canvas"] == [400, 500]  # CSS size x devicePixelRatio
    assert all(run[name]["drawCalls"] > 100 for name in CASES)


@pytest.mark.parametrize("name", ["rest", "m", "m_wide_jaw", "press", "tongue_out_sealed", "tongue_sealed"])
def test_closed_lips_meet_without_a_gap(run, name):
    shape = run[name]["shape"]
    assert shape["opening"] == 0
    assert shape["upperInner"] == shape["lowerInner"]


def test_open_vowel_opens_the_mouth_and_drops_the_jaw(run):
    a, rest = run["a"]["shape"], run["rest"]["shape"]
    assert a["jawDrop"] == pytest.approx(30)
    assert a["opening"] > 20
    assert all(lo >= up for up, lo in zip(a["upperInner"], a["lowerInner"]))
    assert mid(a["lowerOuter"]) - mid(rest["lowerOuter"]) > 20
    assert 0 < run["a_half_closed"]["shape"]["opening"] < a["opening"]


def test_rounding_narrows_and_spreading_widens(run):
    rest, u, i, t = (run[k]["shape"] for k in ("rest", "u", "i", "t"))
    assert width(u) < 0.75 * width(rest)
    assert width(i) > 1.1 * width(rest)
    assert i["lowerInner"][0] < t["lowerInner"][0] - 5  # same jaw: corners go up with a smile


def test_left_channels_move_the_viewers_right(run):
    rest, smile = run["rest"]["shape"], run["smile_left"]["shape"]
    assert smile["x"][-1] > rest["x"][-1] + 5 and smile["x"][0] == pytest.approx(rest["x"][0])
    assert smile["upperInner"][-1] < rest["upperInner"][-1] - 5
    assert smile["upperInner"][0] == pytest.approx(rest["upperInner"][0])


def test_lip_raisers_and_roll(run):
    rest, f = run["rest"]["shape"], run["f"]["shape"]
    assert mid(run["upper_up"]["shape"]["upperInner"]) < mid(rest["upperInner"]) - 5
    assert mid(run["lower_down"]["shape"]["lowerInner"]) > mid(rest["lowerInner"]) + 5
    thickness = lambda s: mid(s["lowerOuter"]) - mid(s["lowerInner"])  # noqa: E731
    assert thickness(f) < 0.5 * thickness(rest)
    assert f["opening"] > 0  # upper teeth show over the tucked lower lip


def test_tongue(run):
    assert run["t"]["shape"]["tipRaise"] == 1
    assert run["a"]["shape"]["tipRaise"] == 0
    assert run["jaw_only"]["shape"]["tipRaise"] == 0  # no guess from the jaw: only tongueTipUp raises the tip
    assert run["tongue_out"]["shape"]["tongueOut"] == 1
    assert run["tongue_out_sealed"]["shape"]["tongueOut"] == 0


def tongue_fills(case, part=None):
    """The tongue's fills (``part``: "tongue" the front part, "tongueBody" the body; all if None) drawn in ``case``."""
    colours = dict(re.findall(r'\b(tongue\w*): "(#[0-9a-f]{6})"', script()))
    wanted = {colours[part]} if part else set(colours.values())
    return [f[1:] for f in case["fills"] if f[0] in wanted]


def tongue_box(case):
    """[x0, y0, x1, y1] around all the tongue's fills in ``case``."""
    boxes = tongue_fills(case)
    assert boxes
    return [min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes)]


def test_tongue_tip_follows_tongue_tip_up(run):
    rest, up = run["tongue_rest"], run["tip_up"]
    assert rest["shape"]["tipRaise"] == 0 and up["shape"]["tipRaise"] == 1
    assert up["shape"]["tongue"]["tipY"] < rest["shape"]["tongue"]["tipY"] - 4  # drawing units, y down
    assert up["shape"]["tongue"]["top"] == rest["shape"]["tongue"]["top"]  # the front part stays on the jaw
    # drawn: the tongue reaches higher, inside the opening between the lips
    assert tongue_box(up)[1] < tongue_box(rest)[1] - 4
    assert mid(up["shape"]["upperInner"]) < tongue_box(up)[1] < mid(up["shape"]["lowerInner"])


def test_tongue_body_follows_tongue_body_up(run):
    rest, up = run["tongue_rest"], run["body_up"]
    assert rest["shape"]["bodyRaise"] == 0 and up["shape"]["bodyRaise"] == 1
    assert up["shape"]["tongue"]["bodyY"] < rest["shape"]["tongue"]["bodyY"] - 4
    assert up["shape"]["tongue"]["tipY"] == rest["shape"]["tongue"]["tipY"]
    # drawn: a body behind the front part, rising above it, broader than the tip
    assert tongue_fills(rest, "tongueBody") == []
    (body,) = tongue_fills(up, "tongueBody")
    (front,) = tongue_fills(up, "tongue")
    assert body[1] < front[1] - 4
    assert body[1] < tongue_box(rest)[1] - 4
    tip = [b for b in tongue_fills(run["tip_up"], "tongue") if b[1] < front[1]]
    assert tip and body[2] - body[0] > 1.5 * (tip[0][2] - tip[0][0])


def test_tongue_back_draws_the_tongue_back(run):
    rest, back = run["tongue_rest"]["shape"]["tongue"], run["tongue_back"]["shape"]["tongue"]
    assert run["tongue_back"]["shape"]["tongueBack"] == 1
    assert back["halfWidth"] < 0.8 * rest["halfWidth"]
    assert back["top"] > rest["top"] + 3
    assert back["tipY"] > rest["tipY"] + 3
    # drawn: a smaller front part, lower down
    before, after = tongue_box(run["tongue_rest"]), tongue_box(run["tongue_back"])
    assert after[2] - after[0] < 0.8 * (before[2] - before[0])
    assert after[1] > before[1] + 3


def test_sealed_lips_hide_the_tongue(run):
    assert tongue_fills(run["tongue_rest"])  # the same jaw with the lips apart shows it
    sealed = run["tongue_sealed"]
    assert sealed["shape"]["opening"] == 0
    assert tongue_fills(sealed) == []
    assert sealed["shape"]["tongueOut"] == 0


def test_out_of_range_weights_are_clamped(run):
    junk = run["junk"]["shape"]
    assert junk["jawDrop"] == 0 and junk["opening"] == 0
    assert junk == run["smile_left"]["shape"]  # pucker -3 counts as 0, smile 7 as 1
