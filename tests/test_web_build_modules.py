"""The web app's pure modules (web/src) run under Node: name matching, file readers, clocks."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import require

WEB_SRC = Path(__file__).resolve().parents[1] / "web" / "src"
LIVE_LINK_HEADER = (
    "Timecode,BlendshapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,"
    "EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,MouthFunnel,MouthPucker,"
    "MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,"
    "MouthDimpleRight,MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,"
    "MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,"
    "MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,"
    "CheekSquintLeft,CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,"
    "LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)


def run_node(script: str):
    """Run an ES-module `script` (web/src importable as ./name.js) and return what it prints as JSON."""
    node = shutil.which("node")
    require(node is not None, "Node.js (node on PATH)")
    require(WEB_SRC.is_dir(), f"the web app's sources ({WEB_SRC})")
    result = subprocess.run(
        [node, "--input-type=module", "-e", script], cwd=WEB_SRC, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_morph_target_names_match_arkit_and_the_tongue_channels():
    names = ["jawOpen", "JawOpen", "blendShape1.jawOpen", "eyeBlink_L", "EYEBLINK_R", "mouth_L",
             "browInnerUp_R", "cheekPuffLeft", "blendShape1.MouthSmile_R", "viseme_aa", "HeadYaw", "jaw",
             "tongueTipUp", "TongueBack", "tongue"]
    got = run_node(f"import {{ morphName }} from './arkit.js'; "
                   f"console.log(JSON.stringify({json.dumps(names)}.map(morphName)))")
    assert got == ["jawOpen", "jawOpen", "jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthLeft",
                   "browInnerUp", "cheekPuff", "mouthSmileRight", None, None, None,
                   "tongueTipUp", "tongueBack", None]


def test_the_page_knows_every_morph_channel_python_does():
    from vispeech.motion.arkit import MORPH_NAMES

    assert run_node("import { MORPH_NAMES } from './arkit.js'; console.log(JSON.stringify(MORPH_NAMES))") == list(
        MORPH_NAMES)


def sample_script(text: str, times: list[float]) -> str:
    return (
        "import { parseAnimation } from './animation.js';"
        f"const a = parseAnimation({json.dumps(text)}, 'test');"
        "const jaw = a.channels.findIndex((c) => c.toLowerCase() === 'jawopen');"
        f"console.log(JSON.stringify({{fps: a.fps, n: a.length, start: a.startTime, channels: a.channels.length,"
        f" jaw: {json.dumps(times)}.map((t) => a.sample(t)[jaw])}}));"
    )


def test_vispeech_json_is_sampled_on_its_own_timeline():
    doc = {"format": "vispeech-animation", "version": 1, "fps": 25, "start_time": 0.5,
           "channels": ["mouthClose", "jawOpen"], "frames": [[0, 0.0], [0, 0.4], [0, 0.8]],
           "phones": {"language": "sv", "words": [], "phones": []}}
    got = run_node(sample_script(json.dumps(doc), [0.0, 0.5, 0.54, 0.58, 1.0]))
    assert (got["fps"], got["n"], got["start"], got["channels"]) == (25, 3, 0.5, 2)
    # held before the first frame and after the last, linear in between (frame k at 0.5 + k/25 s)
    assert got["jaw"] == pytest.approx([0.0, 0.0, 0.4, 0.8, 0.8], abs=1e-6)


def test_live_link_csv_timecodes_give_fps_and_times():
    columns = LIVE_LINK_HEADER.split(",")[2:]
    rows = [LIVE_LINK_HEADER]
    for k, jaw in enumerate([0.0, 0.2, 0.6, 0.2]):  # 30 fps rows in 60 fps timecode: FF steps by 2
        values = ["%.10f" % (jaw if name == "JawOpen" else 0.0) for name in columns]
        rows.append(",".join([f"19:16:29:{40 + 2 * k:02d}.000", "61", *values]))
    got = run_node(sample_script("\r\n".join(rows) + "\r\n", [0.0, 1 / 30, 2 / 30, 2.5 / 30, 1.0]))
    assert (got["fps"], got["n"], got["channels"]) == (30, 4, 61)
    assert got["jaw"] == pytest.approx([0.0, 0.2, 0.6, 0.4, 0.2], abs=1e-6)


@pytest.mark.parametrize("fps,every", [(12, 1), (15, 1), (20, 1), (25, 1), (59, 1), (144, 1), (60, 5)])
def test_live_link_csv_reads_at_the_rate_vispeech_reads_it(fps, every):
    """As the Python reader: a take that wraps counts frames at the rate where FF wraps, not the
    next nominal one (12 fps is not 24, 59 not 60), unless its rows step over frame numbers (every
    5th frame of a 60 fps timecode ends at 55: 12 fps on a 60 fps timecode)."""
    rate, fps = fps, fps // every
    rows = ["Timecode,BlendshapeCount,JawOpen"]
    for k in range(2 * fps + 3):  # a little over two seconds, row k at k / fps
        frame = k * every
        rows.append(f"00:00:{frame // rate:02d}:{frame % rate:02d}.000,1,{k % 2}.0000000000")
    got = run_node(sample_script("\n".join(rows) + "\n", [0.0, 1 / fps, 2 / fps, fps / fps]))
    assert (got["fps"], got["n"]) == (fps, 2 * fps + 3)
    assert got["jaw"] == pytest.approx([0.0, 1.0, 0.0, fps % 2], abs=1e-6)


def test_talkinghead_frames_start_where_the_durations_before_them_end():
    doc = {"anim": {"name": "speech", "dt": [100, 100, 100], "vs": {"jawOpen": [0.3, None, [0.5, 0.7]]}}}
    got = run_node(sample_script(json.dumps(doc), [0.0, 0.1, 0.15, 0.2, 0.3]))
    assert (got["fps"], got["n"]) == (10, 3)
    assert got["jaw"] == pytest.approx([0.3, 0.3, 0.45, 0.6, 0.6], abs=1e-6)


@pytest.mark.parametrize("suffix", [".json", ".csv", ".talkinghead.json"])
def test_files_vispeech_writes_read_back_frame_for_frame(tmp_path, suffix):
    """The player reads vispeech's own writers' files onto the same timeline, to 6 decimals."""
    from vispeech.motion.formats.registry import write_track
    from vispeech.motion.track import Track

    rng = np.random.default_rng(3)
    channels = ("jawOpen", "mouthClose", "eyeBlinkLeft", "mouthSmileRight")
    start = 0.0 if suffix == ".talkinghead.json" else 0.5  # TalkingHead has no start time
    track = Track(rng.uniform(0, 1, (37, len(channels))), channels, 30.0, start)
    path = tmp_path / f"take{suffix}"
    write_track(track, path)
    script = (
        "import { parseAnimation } from './animation.js'; import { morphName } from './arkit.js';"
        f"const a = parseAnimation({json.dumps(path.read_text(encoding='utf-8'))}, 'take');"
        f"const want = {json.dumps(channels)};"
        "const cols = want.map((n) => a.channels.findIndex((c) => morphName(c) === n));"
        "const rows = [...Array(a.length).keys()].map((k) => [...a.sample(a.startTime + k / a.fps)]);"
        "console.log(JSON.stringify({fps: a.fps, start: a.startTime, rows: rows.map((r) => cols.map((c) => r[c]))}));"
    )
    got = run_node(script)
    assert got["fps"] == pytest.approx(30.0) and got["start"] == pytest.approx(start, abs=1e-6)
    assert np.array(got["rows"]) == pytest.approx(track.values, abs=2e-6)


_FRAMES = '{"format": "vispeech-animation", "version": 1, "fps": %s, "channels": ["jawOpen"], "frames": %s}'


@pytest.mark.parametrize("text,words", [
    ('{"format": "vispeech-animation", "version": 2, "fps": 30}', "version 2"),
    ('{"hello": 1}', "neither"), ("a,b\n1,2\n", "not a vispeech JSON"), ("{not json", "not valid JSON"),
    # refused as vispeech's readers refuse them, not shown as a vanished head or an empty take
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,0.1\n00:00:00:01.000,1,abc\n", "line 3: a value is not"),
    ("Timecode,BlendshapeCount,JawOpen\n00:00:00:00.000,1,0.1\n00:00:00:01.000,1,\n", "line 3: a value is not"),
    (_FRAMES % (30, '[[0.1], ["0.2"]]'), 'frame 1, value 0 is not a number ("0.2")'),
    (_FRAMES % (30, "[]"), 'a non-empty "frames" array'),
    (_FRAMES % (0, "[[0.1]]"), "fps must be positive"),  # the Animation's own error, named by the file too
])
def test_unreadable_animation_files_raise_one_clear_error(text, words):
    script = ("import { parseAnimation } from './animation.js';"
              f"try {{ parseAnimation({json.dumps(text)}, 'x.json'); console.log('null') }}"
              "catch (e) { console.log(JSON.stringify(e.message)) }")
    message = run_node(script)
    assert message.startswith("x.json: ") and "\n" not in message and words in message, message


def test_idle_blinks_come_every_two_to_six_seconds():
    got = run_node(
        "import { IdleMotion } from './idle.js';"
        "const idle = new IdleMotion(7); const starts = []; let prev = 0; let head = 0;"
        "for (let i = 0; i <= 120 * 100; i++) { const t = i / 100; const b = idle.blink(t);"
        " if (b > 0 && prev === 0) starts.push(t); prev = b;"
        " head = Math.max(head, ...idle.head(t).map(Math.abs)); }"
        "console.log(JSON.stringify({ starts, head }));"
    )
    gaps = [b - a for a, b in zip(got["starts"], got["starts"][1:])]
    assert len(got["starts"]) >= 15
    assert min(gaps) >= 2.0 - 0.011 and max(gaps) <= 6.0 + 0.011
    assert 0.005 < got["head"] < 0.04  # radians: visible sway, never more than ~2 degrees


def test_streamed_pcm16_decodes_little_endian():
    got = run_node(
        "import { decodePcm16 } from './performer.js';"
        "const b = Buffer.from(new Int16Array([0, 16384, -32768, 32767]).buffer).toString('base64');"
        "console.log(JSON.stringify([...decodePcm16(b)]));"
    )
    assert got == pytest.approx([0.0, 0.5, -1.0, 32767 / 32768])


def test_an_utterances_layers_take_over_the_head_and_blinks_without_a_jump():
    script = """
    import { Performer } from './performer.js';
    import { Animation } from './animation.js';
    import { MORPH_INDEX } from './arkit.js';
    let clock = 0;  // seconds: the page's and the audio's clock, ticked at 60 Hz
    const context = { get currentTime() { return clock; }, state: 'running', resume: async () => {} };
    globalThis.AudioContext = class { constructor() { return context; } };
    Object.defineProperty(globalThis, 'performance', { value: { now: () => clock * 1000 }, configurable: true });
    const fps = 30, n = 20 * fps;  // 20 s: idle motion would blink several times
    const channels = ['jawOpen', 'eyeBlinkLeft', 'eyeBlinkRight', 'headYaw', 'headPitch', 'headRoll', 'breath'];
    const frames = [...Array(n).keys()].map((k) => {
      const t = k / fps, blink = Math.abs(t - 10) < 0.1 ? 1 : 0;
      return [0.3, blink, blink, 3 * Math.sin(t), 1.7, -1.1, 0.5 + 0.5 * Math.sin(t / 3)];  // head in degrees
    });
    const run = (idle, animation) => {
      const heads = [], blinks = [], times = [], clocks = [];
      const avatar = { blinks: false, render() {}, setHeadRotation: (...pose) => heads.push(pose),
        setWeights: (w) => blinks.push(w[MORPH_INDEX.get('eyeBlinkLeft')]) };
      clock = 0;
      const performer = new Performer(avatar, { idle });
      for (let i = 0; i < 60 * 25; i++) {
        clock = i / 60;
        if (i === 60) {  // after a second of idle motion
          performer.load(animation);
          performer.play(0);
        }
        performer.tick();
        times.push(performer.time());
        clocks.push(clock);
      }
      return { heads, blinks: blinks.slice(-times.length), times, clocks };
    };
    const anim = () => new Animation({ fps, channels, frames });
    const plain = new Animation({ fps, channels: ['jawOpen'], frames: frames.map((f) => [f[0]]) });
    console.log(JSON.stringify({ lively: run(true, anim()), still: run(false, plain), bare: run(false, anim()) }));
    """
    got = run_node(script)
    lively = got["lively"]
    heads = np.array(lively["heads"])
    assert np.abs(np.diff(heads, axis=0)).max() < 0.006  # never a jump, also where the utterance starts and ends
    times, blinks, clocks = np.array(lively["times"]), np.array(lively["blinks"]), np.array(lively["clocks"])
    during = (times > 1) & (times < 19) & (clocks < 21)
    t = times[during]
    pose = heads[-len(times):][during]  # [pitch, yaw, roll] in radians: the track's head, tilted up by the breath
    np.testing.assert_allclose(pose[:, 1], np.radians(3 * np.sin(t)), atol=2e-3)
    np.testing.assert_allclose(pose[:, 0], np.radians(1.7) - 0.01 * (0.5 + 0.5 * np.sin(t / 3)), atol=1e-3)
    np.testing.assert_allclose(pose[:, 2], np.radians(-1.1), atol=1e-6)
    assert blinks[during].max() == pytest.approx(1, abs=0.01)  # the track's one blink at 10 s...
    assert blinks[during & (np.abs(times - 10) > 0.2)].max() == 0  # ...and no idle blinks
    assert blinks[clocks > 22].max() > 0.5  # idle blinks are back after it
    assert got["still"]["heads"] == []  # idle=0 and no layers: the head is never moved
    bare = np.array(got["bare"]["heads"])
    assert np.abs(bare[-1]).max() == 0 and np.abs(np.diff(bare, axis=0)).max() < 0.006


def _vrm_expressions(poses: list[dict[str, float]]) -> dict:
    """The lip aperture and VRM expressions (web/src/expressions.js) of ARKit ``poses`` (channel -> weight)."""
    script = (
        "import { MORPH_NAMES } from './arkit.js'; import { lipAperture, vrmExpressions } from './expressions.js';"
        f"const poses = {json.dumps(poses)};"
        "const weights = poses.map((p) => MORPH_NAMES.map((n) => p[n] || 0));"
        "console.log(JSON.stringify({aperture: weights.map(lipAperture), expressions: weights.map(vrmExpressions)}));"
    )
    return run_node(script)


def test_a_vrm_mouth_opens_as_far_as_the_lips_part_as_python_measures_them():
    from vispeech.motion.arkit import ARKIT_NAMES, LIP_CLOSED, lip_aperture
    from vispeech.motion.track import Track

    rng = np.random.default_rng(5)
    values = rng.uniform(0, 1, (40, len(ARKIT_NAMES))) * rng.uniform(0, 0.6, (40, 1))
    got = _vrm_expressions([dict(zip(ARKIT_NAMES, row)) for row in values.tolist()])
    assert got["aperture"] == pytest.approx(lip_aperture(Track(values, ARKIT_NAMES, 30.0)).tolist(), abs=1e-9)
    aperture = np.array(got["aperture"])
    vowels = np.array([[e[v] for v in ("aa", "ee", "oh", "ih", "ou")] for e in got["expressions"]])
    assert (vowels >= 0).all() and (vowels.sum(axis=1) <= 1 + 1e-9).all()
    closed = aperture <= LIP_CLOSED
    assert closed.any() and (~closed).any()
    assert (vowels[closed] == 0).all()  # closed lips: the mouth at rest
    # the open vowels together open as far as the lips part past closed, in full from an aperture of 0.4
    opening = np.clip((aperture - LIP_CLOSED) / (0.4 - LIP_CLOSED), 0, 1)
    assert vowels[:, :3].sum(axis=1) == pytest.approx(opening, abs=1e-9)


def test_a_vrm_shows_open_rounded_spread_and_closed_lips_by_its_presets():
    poses = {
        "open": {"jawOpen": 0.4},
        "rounded": {"jawOpen": 0.4, "mouthFunnel": 0.5},
        "spread": {"jawOpen": 0.4, "mouthStretchLeft": 0.5, "mouthStretchRight": 0.5},
        "u": {"jawOpen": 0.08, "mouthPucker": 0.6},
        "m": {"jawOpen": 0.2, "mouthClose": 0.2, "mouthPucker": 0.4, "mouthPressLeft": 0.3, "mouthPressRight": 0.3},
        "glad": {"cheekSquintLeft": 0.15, "cheekSquintRight": 0.15, "eyeBlinkLeft": 1.0},
    }
    got = dict(zip(poses, _vrm_expressions(list(poses.values()))["expressions"]))
    strongest = {name: max(("aa", "ih", "ou", "ee", "oh"), key=e.get) for name, e in got.items()}
    assert strongest["open"] == "aa" and got["open"]["aa"] == pytest.approx(1.0)
    assert (strongest["rounded"], strongest["spread"], strongest["u"]) == ("oh", "ee", "ou")
    assert max(got["m"][v] for v in ("aa", "ih", "ou", "ee", "oh")) == 0  # lips shut: the mouth at rest
    assert (got["glad"]["happy"], got["glad"]["blinkLeft"], got["glad"]["blinkRight"]) == pytest.approx((0.3, 1, 0))
