"""Tongue channels from the phones' features (issue 10, part 2: the tracks; the head's tongue morphs are not done)."""

from __future__ import annotations

import numpy as np
import pytest

from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.postprocess.overlays import anchor_frames
from vispeech.pipeline import DEFAULT_MODEL, speak

CASES = [
    ("en", "Ned told Lou to think of the cat and the dog.", {"N", "D", "L", "T"}, {"K", "G"}, {"TH", "DH"}),
    ("sv", "Tanten tog en kaka och gick till bordet.", {"t", "d", "n", "l", "rd"}, {"k", "g"}, set()),
    ("de", "Der Tag ist lang, nimm den Kuchen.", {"t", "d", "n", "l"}, {"k", "ɡ", "ŋ"}, set()),
]


@pytest.mark.parametrize("model", [DEFAULT_MODEL, "baseline"])
@pytest.mark.parametrize(("lang", "text", "tip", "body", "out"), CASES, ids=[c[0] for c in CASES])
def test_tip_body_and_out_follow_the_phones(model, lang, text, tip, body, out):
    said = speak(text, lang, model=model)
    track = said.track
    assert set(TONGUE_CHANNELS) <= set(track.channels)
    spoken = [p for p in said.phones if not p.is_silence]
    frames = anchor_frames(np.array([p.start for p in spoken]), np.array([p.end for p in spoken]), track.fps,
                           track.n_frames)
    seen = {"tip": 0, "body": 0, "out": 0}
    for phone, k in zip(spoken, frames):
        if phone.symbol in tip:
            assert track["tongueTipUp"][k] >= 0.8 and track["tongueOut"][k] < 0.1, (phone, k)
            seen["tip"] += 1
        if phone.symbol in body:
            assert track["tongueBodyUp"][k] >= 0.8 and track["tongueTipUp"][k] < 0.5, (phone, k)
            seen["body"] += 1
        if phone.symbol in out:
            assert track["tongueOut"][k] >= 0.5, (phone, k)
            seen["out"] += 1
    assert seen["tip"] >= 3 and seen["body"] >= 1 and (seen["out"] >= 1 or not out)
    assert np.all((track.select(TONGUE_CHANNELS).values >= 0) & (track.select(TONGUE_CHANNELS).values <= 1))
    rest = track.select(TONGUE_CHANNELS).values[-2:]
    np.testing.assert_allclose(rest, 0.0, atol=1e-9)  # at rest after speech
