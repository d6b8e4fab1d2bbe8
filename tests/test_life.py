"""Non-verbal layers (issue 10, part 3): seeded, separable, at human rates, exported like speech."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import find_peaks

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.motion.formats.livelink import read_livelink_csv, write_livelink_csv
from vispeech.motion.life import CHANNELS, LAYERS, check_layers, nonverbal, with_life
from vispeech.motion.track import Track

FPS = 30.0


def test_blinks_come_at_a_human_rate_and_close_the_eyes():
    minute = nonverbal(int(60 * FPS), FPS, layers=["blink"], seed=3)
    assert minute.channels == CHANNELS["blink"]
    blinks, _ = find_peaks(minute["eyeBlinkLeft"], height=0.5)
    assert 10 <= len(blinks) <= 30  # people blink about 15-20 times a minute at rest
    assert minute["eyeBlinkLeft"].max() == pytest.approx(1.0, abs=0.15)
    np.testing.assert_array_equal(minute["eyeBlinkLeft"], minute["eyeBlinkRight"])
    closed = minute["eyeBlinkLeft"] > 0.5
    assert closed.mean() < 0.08  # the eyes are open nearly all the time


def test_layers_are_seeded_and_separable():
    a = nonverbal(300, FPS, seed=1)
    b = nonverbal(300, FPS, seed=1)
    c = nonverbal(300, FPS, seed=2)
    np.testing.assert_array_equal(a.values, b.values)
    assert not np.array_equal(a.values, c.values)
    assert a.channels == tuple(dict.fromkeys(c for layer in LAYERS for c in CHANNELS[layer]))
    head_only = nonverbal(300, FPS, layers=["head"], seed=1)
    np.testing.assert_array_equal(head_only.values, a.select(CHANNELS["head"]).values)  # independent of the others
    assert 0.5 < np.abs(head_only.values).max() < 4  # degrees: moving, within about 4
    gaze = nonverbal(300, FPS, layers=["gaze"], seed=1)
    assert 0 < gaze.values.max() <= 0.25


def test_nods_and_brows_follow_stressed_vowels():
    timed = [("sil", 0.0, 0.5), ("HH", 0.5, 0.6), ("AH", 0.6, 0.7, 0), ("L", 0.7, 0.8), ("OW", 0.8, 1.0, 1),
             ("sil", 1.0, 2.0), ("K", 2.0, 2.1), ("AE", 2.1, 2.3, 1), ("T", 2.3, 2.4), ("sil", 2.4, 3.0)]
    phones = PhoneSequence([Phone(t[0], t[1], t[2], None, t[3] if len(t) > 3 else 0) for t in timed], "en")
    still = nonverbal(90, FPS, layers=["head", "brows"], seed=4)
    lively = nonverbal(90, FPS, phones, layers=["head", "brows"], seed=4)
    nod = lively["headPitch"] - still["headPitch"]
    assert nod[int(0.95 * FPS)] > 1 and nod[int(2.25 * FPS)] > 1 and abs(nod[int(1.6 * FPS)]) < 1e-9  # degrees
    brows = lively["browInnerUp"]
    assert brows[int(0.95 * FPS)] > 0.2 and brows[int(2.3 * FPS)] > 0.2 and brows[int(1.6 * FPS)] == 0
    assert still["browInnerUp"].max() == 0  # no phones, no emphasis


def test_with_life_keeps_the_speech_and_live_link_carries_the_layers(tmp_path):
    speech = Track(np.random.default_rng(0).uniform(0, 0.5, (90, 2)), ("jawOpen", "mouthClose"), FPS)
    lively = with_life(speech, None, ["blink", "head"], seed=5)
    np.testing.assert_array_equal(lively.select(speech.channels).values, speech.values)
    write_livelink_csv(lively, tmp_path / "take.csv")
    back = read_livelink_csv(tmp_path / "take.csv")
    np.testing.assert_allclose(back["eyeBlinkLeft"], lively["eyeBlinkLeft"], atol=1e-9)
    np.testing.assert_allclose(back["headYaw"], lively["headYaw"], atol=1e-9)
    assert with_life(speech, None, []) is speech


def _phones(timed):
    return PhoneSequence([Phone(t[0], t[1], t[2], None, t[3] if len(t) > 3 else 0) for t in timed], "en")


def test_breathing_rests_at_a_human_rate():
    for seed in range(4):
        breath = nonverbal(int(120 * FPS), FPS, layers=["breath"], seed=seed)
        assert breath.channels == ("breath",)
        breaths, _ = find_peaks(breath["breath"], prominence=0.1)
        assert 10 <= len(breaths) / 2 <= 20  # 12-15 a minute at rest
        assert 0 <= breath["breath"].min() and breath["breath"].max() <= 1
        assert np.abs(np.diff(breath["breath"])).max() < 0.05  # smooth
    again = nonverbal(int(120 * FPS), FPS, layers=["breath"], seed=3)
    np.testing.assert_array_equal(again.values, breath.values)
    assert not np.array_equal(nonverbal(int(120 * FPS), FPS, layers=["breath"], seed=4).values, breath.values)


def test_a_breath_is_taken_before_speech_and_let_out_while_speaking():
    phones = _phones([("sil", 0.0, 1.0), ("HH", 1.0, 1.1), ("AH", 1.1, 1.3), ("L", 1.3, 1.5), ("sil", 1.5, 1.7),
                      ("OW", 1.7, 2.5), ("sil", 2.5, 3.5), ("K", 3.5, 3.6), ("AE", 3.6, 4.3), ("T", 4.3, 4.4),
                      ("sil", 4.4, 8.0)])
    for seed in range(4):
        breath = nonverbal(int(8 * FPS), FPS, phones, layers=["breath"], seed=seed)["breath"]
        at = lambda t: breath[round(t * FPS)]  # noqa: E731
        assert 0 <= breath.min() and breath.max() <= 1
        for onset, end in ((1.0, 2.5), (3.5, 4.4)):  # the 0.2 s pause at 1.5 s takes no breath
            assert at(onset) > at(onset - 0.5) + 0.2  # a quick inhalation just before speaking
            assert at(onset) >= breath[round((onset - 0.6) * FPS):round((onset + 0.1) * FPS)].max() - 0.05
            middle = (onset + end) / 2
            assert at(onset) > at(middle) > at(end - 0.05)  # let out while speaking
        assert at(1.5) > at(1.7) > at(1.9)  # no breath in a short pause
        assert at(1.0) > at(3.5)  # the longer stretch takes the deeper breath


def test_breath_goes_to_json_not_to_live_link(tmp_path):
    from vispeech.motion.formats.animation_json import read_animation_json, write_animation_json

    speech = Track(np.zeros((90, 1)), ("jawOpen",), FPS)
    lively = with_life(speech, None, ["blink", "breath"], seed=1)
    assert "breath" in lively.channels and lively["breath"].max() > 0
    write_livelink_csv(lively, tmp_path / "take.csv")
    header = (tmp_path / "take.csv").read_text().splitlines()[0].split(",")
    assert "EyeBlinkLeft" in header and "Breath" not in header and "breath" not in header
    write_animation_json(lively, tmp_path / "take.json")
    np.testing.assert_allclose(read_animation_json(tmp_path / "take.json").track["breath"], lively["breath"], atol=1e-6)


def test_layer_names_are_checked():
    assert check_layers("all") == LAYERS and check_layers("head, blink") == ("blink", "head") and check_layers("") == ()
    assert check_layers("breath,brows") == ("brows", "breath")
    with pytest.raises(VispeechError, match="unknown non-verbal layer 'dance'"):
        check_layers("blink,dance")
    with pytest.raises(VispeechError, match="must be 0 or more"):
        nonverbal(10, FPS, seed=-1)


def test_say_adds_the_layers_it_is_asked_for(tmp_path):
    from click.testing import CliRunner

    from vispeech.cli import main

    runner = CliRunner()
    for name, extra in (("plain", []), ("lively", ["--life", "all", "--seed", "2"])):
        done = runner.invoke(main, ["say", "Hello there, my friend.", "-o", str(tmp_path / name), *extra])
        assert done.exit_code == 0, done.output
    plain, lively = (read_livelink_csv(tmp_path / name / "animation.csv") for name in ("plain", "lively"))
    np.testing.assert_allclose(lively["jawOpen"], plain["jawOpen"], atol=1e-9)  # the speech is the same
    assert plain["eyeBlinkLeft"].max() == 0 and np.abs(plain["headYaw"]).max() == 0
    assert np.abs(lively["headYaw"]).max() > 0 and lively["browInnerUp"].max() > 0
    refused = runner.invoke(main, ["say", "hi", "--life", "dance", "-o", str(tmp_path / "no")])
    assert refused.exit_code == 2 and "unknown non-verbal layer" in refused.output


SPOKEN = [("sil", 0.0, 0.5), ("HH", 0.5, 0.6), ("AH", 0.6, 0.7, 0), ("L", 0.7, 0.8), ("OW", 0.8, 1.0, 1),
          ("sil", 1.0, 3.0)]  # fmt: skip


def test_the_expression_smiles_or_frowns_gently_by_the_mood_while_speaking():
    phones = _phones(SPOKEN)
    glad = nonverbal(90, FPS, phones, layers=["expression"], seed=2, mood=0.8)
    sorry = nonverbal(90, FPS, phones, layers=["expression"], seed=2, mood=-0.8)
    neutral = nonverbal(90, FPS, phones, layers=["expression"], seed=2, mood=0.0)
    assert glad.channels == CHANNELS["expression"] and not neutral.values.any()
    speaking = slice(int(0.7 * FPS), int(1.0 * FPS))
    assert 0.15 < glad["mouthSmileLeft"][speaking].mean() < 0.35 and glad["cheekSquintLeft"][speaking].min() > 0.05
    assert not glad["mouthFrownLeft"].any() and not sorry["mouthSmileLeft"].any()
    assert 0.1 < sorry["mouthFrownRight"][speaking].mean() < 0.25 and sorry["browInnerUp"][speaking].min() > 0.15
    assert glad.values[0].max() == 0 and glad.values[int(2.1 * FPS) :].max() == 0  # in before speech, out after it
    assert glad.values.max() <= 0.4  # gently
    again = nonverbal(90, FPS, phones, layers=["expression"], seed=2, mood=0.8)
    other = nonverbal(90, FPS, phones, layers=["expression"], seed=3, mood=0.8)
    np.testing.assert_array_equal(glad.values, again.values)
    assert not np.array_equal(glad.values, other.values)
    with pytest.raises(VispeechError, match="mood"):
        nonverbal(10, FPS, layers=["expression"], mood=1.5)


def test_the_expression_adds_to_the_speech_and_the_brows():
    """The speech's smile (at /i/) stays under the expression's; the brows layer's emphasis and the
    expression's concern sum in one browInnerUp; the other speech channels are untouched."""
    phones = _phones(SPOKEN)
    rng = np.random.default_rng(0)
    speech = Track(rng.uniform(0, 0.5, (90, 3)), ("jawOpen", "mouthSmileLeft", "mouthSmileRight"), FPS)
    expression = nonverbal(90, FPS, phones, layers=["expression"], seed=1, mood=0.9)
    lively = with_life(speech, phones, ["expression"], seed=1, mood=0.9)
    np.testing.assert_array_equal(lively["jawOpen"], speech["jawOpen"])
    np.testing.assert_allclose(lively["mouthSmileLeft"], np.minimum(speech["mouthSmileLeft"] + expression["mouthSmileLeft"], 1))
    both = nonverbal(90, FPS, phones, layers=["brows", "expression"], seed=1, mood=-1.0)
    brows = nonverbal(90, FPS, phones, layers=["brows"], seed=1)
    sorry = nonverbal(90, FPS, phones, layers=["expression"], seed=1, mood=-1.0)
    assert both.channels.count("browInnerUp") == 1
    np.testing.assert_allclose(both["browInnerUp"], np.minimum(brows["browInnerUp"] + sorry["browInnerUp"], 1))
