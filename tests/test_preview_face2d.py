"""The 2D face script's mouth geometry and drawing, run in Node (skipped where Node is missing, failed under CI)."""

import json
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
HARNESS = r"""
const fs = require("fs");
const vm = require("vm");
const [script, cases] = JSON.parse(fs.readFileSync(0, "utf8"));
const calls = [];
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
  face.setWeights(weights, 0.5);
  out[name] = { shape: lib.mouthShape(weights), drawCalls: calls.length };
}
out.canvas = [canvas.width, canvas.height];
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
    "t": {"jawOpen": 0.15},
    "everything": {"jawOpen": 1, "jawForward": 1, "jawLeft": 1, "mouthFunnel": 1, "mouthPucker": 1,
                   "mouthStretchLeft": 1, "eyeBlinkLeft": 1, "cheekPuff": 1, "tongueOut": 1},
    "junk": {"jawOpen": "wide", "mouthClose": None, "mouthPucker": -3, "mouthSmileLeft": 7},
}


@pytest.fixture(scope="module")
def run():
    script = resources.files("vispeech.preview").joinpath("face2d.js").read_text(encoding="utf-8")
    done = subprocess.run([NODE, "-e", HARNESS], input=json.dumps([script, CASES]), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def width(shape):
    return shape["x"][-1] - shape["x"][0]


def mid(values):
    return values[len(values) // 2]


def test_every_case_draws(run):
    assert run["canvas"] == [400, 500]  # CSS size x devicePixelRatio
    assert all(run[name]["drawCalls"] > 100 for name in CASES)


@pytest.mark.parametrize("name", ["rest", "m", "m_wide_jaw", "press", "tongue_out_sealed"])
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
    assert run["t"]["shape"]["tipRaise"] > 0.5
    assert run["a"]["shape"]["tipRaise"] < 0.01
    assert run["tongue_out"]["shape"]["tongueOut"] == 1
    assert run["tongue_out_sealed"]["shape"]["tongueOut"] == 0


def test_out_of_range_weights_are_clamped(run):
    junk = run["junk"]["shape"]
    assert junk["jawDrop"] == 0 and junk["opening"] == 0
    assert junk == run["smile_left"]["shape"]  # pucker -3 counts as 0, smile 7 as 1
