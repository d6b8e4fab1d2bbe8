"""Voice activity (issue 22 part 4): Silero VAD window by window, and live audio streams whose
mouth rests between utterances."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import soundfile
from conftest import SHARED, require, require_module

from vispeech.frontends.audio import AudioClip
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL, animate_audio
from vispeech.postprocess import PostprocessConfig
from vispeech.postprocess.rest import EASE, HOLD, REST_CHANNELS
from vispeech.streaming import LiveAudioStream

require_module("onnxruntime", "ONNX Runtime (the serve extra)")
from vispeech.frontends.vad import SAMPLE_RATE, WINDOW, VoiceActivity  # noqa: E402

CLIP = SHARED / "data" / "grid_s1" / "utterances" / "bbaf2n.flac"
"""'bin blue at f two now': 'bin' from 0.95 s to 1.21 s, 'now' ends at 2.05 s (the corpus's timing)."""
GAP = 1.5
"""Seconds of silence between two takes of the clip."""


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


def test_a_live_stream_rests_between_utterances_and_keeps_the_speech(samples, monkeypatch):
    """Two takes of a GRID clip 1.5 s apart through the live model: the mouth is at rest in the
    middle of the gap, and within the speech each frame is the model's own."""
    audio = np.concatenate([samples, np.zeros(int(GAP * SAMPLE_RATE), np.float32), samples])
    pcm16 = (audio * 32767).astype("<i2")
    pcm = pcm16.tobytes()
    model = load_model(DEFAULT_AUDIO_STREAM_MODEL)

    def streamed() -> tuple[LiveAudioStream, np.ndarray]:
        stream = LiveAudioStream(model, SAMPLE_RATE, 25.0)
        rows = [stream.push(pcm[i:i + 640])[1] for i in range(0, len(pcm), 640)]
        return stream, np.concatenate([*rows, stream.finish()[1]])

    stream, frames = streamed()
    assert stream.activity is not None and len(stream.activity.spans) == 2
    monkeypatch.setattr("vispeech.frontends.vad.installed", lambda: False)
    plain_stream, plain = streamed()
    assert plain_stream.activity is None
    config = replace(PostprocessConfig.from_preset(model.postprocessing), rest=False)
    offline = animate_audio(AudioClip.from_array(pcm16, SAMPLE_RATE), model, 25.0, config)
    np.testing.assert_allclose(plain, offline.select(plain_stream.channels).values, atol=1e-4)

    times = np.arange(len(frames)) / 25.0
    spans = stream.activity.spans
    resting = [stream.channels.index(c) for c in REST_CHANNELS if c in stream.channels]
    jaw = stream.channels.index("jawOpen")
    gap = (times > spans[0, 1] + HOLD + EASE) & (times < spans[1, 0] - HOLD - EASE)
    assert gap.sum() >= 10
    assert np.all(frames[np.ix_(gap, resting)] == 0)
    assert plain[gap, jaw].max() > 0.02  # the model alone keeps the jaw open in the gap
    inside = np.zeros(len(times), bool)
    for start, end in spans:
        inside |= (times >= start) & (times <= end)
    np.testing.assert_array_equal(frames[inside], plain[inside])
