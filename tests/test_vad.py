"""Voice activity (issue 22 part 4): Silero VAD window by window."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile
from conftest import SHARED, require, require_module

require_module("onnxruntime", "ONNX Runtime (the serve extra)")
from vispeech.frontends.vad import SAMPLE_RATE, WINDOW, VoiceActivity  # noqa: E402

CLIP = SHARED / "data" / "grid_s1" / "utterances" / "bbaf2n.flac"
"""'bin blue at f two now': 'bin' from 0.95 s to 1.21 s, 'now' ends at 2.05 s (the corpus's timing)."""


@pytest.fixture(scope="module")
def samples() -> np.ndarray:
    require(CLIP.is_file(), f"grid_s1 ({CLIP})")
    audio, rate = soundfile.read(CLIP, dtype="float32")
    assert rate == SAMPLE_RATE
    return audio


def test_pieces_of_any_size_give_what_the_whole_gives(samples):
    whole = VoiceActivity()
    expected = whole.push(samples)
    assert len(expected) == len(samples) // WINDOW
    pieced, got, at = VoiceActivity(), [], 0
    rng = np.random.default_rng(3)
    while at < len(samples):
        n = int(rng.integers(1, 3 * WINDOW))
        got.append(pieced.push(samples[at:at + n]))
        at += n
    np.testing.assert_array_equal(np.concatenate(got), expected)
    np.testing.assert_array_equal(pieced.spans, whole.spans)


def test_speech_is_found_where_the_words_are_and_nowhere_in_silence(samples):
    activity = VoiceActivity()
    activity.push(np.concatenate([samples, np.zeros(SAMPLE_RATE, np.float32), samples]))
    spans = activity.spans
    assert len(spans) == 2, spans
    duration = len(samples) / SAMPLE_RATE
    for (start, end), offset in zip(spans, (0.0, duration + 1.0)):
        assert 0.9 <= start - offset <= 1.05 and 2.0 <= end - offset <= 2.3  # within a window or two
    quiet = VoiceActivity()
    noise = np.random.default_rng(0).normal(0, 0.003, 3 * SAMPLE_RATE).astype(np.float32)
    assert quiet.push(noise).max() < 0.5 and len(quiet.spans) == 0
