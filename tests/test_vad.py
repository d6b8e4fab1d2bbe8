"""Voice activity (issue 22 part 4): Silero VAD window by window (on NumPy, as ONNX Runtime runs
the shipped model), many streams' windows at once, and live audio streams whose mouth rests
between utterances."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import soundfile
from conftest import SHARED, require, require_module

from vispeech.frontends import silero
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.vad import CONTEXT, SAMPLE_RATE, WINDOW, VoiceActivity
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_AUDIO_STREAM_MODEL, animate_audio
from vispeech.postprocess import PostprocessConfig
from vispeech.postprocess.rest import EASE, HOLD, REST_CHANNELS
from vispeech.streaming import LiveAudioStream, push_audio_together

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
    np.testing.assert_allclose(np.concatenate(got), expected, atol=1e-6)
    np.testing.assert_array_equal(pieced.spans, whole.spans)


def test_the_network_gives_what_onnx_runtime_gives(samples):
    """The NumPy port of the shipped graph, against ONNX Runtime on the file itself."""
    onnxruntime = require_module("onnxruntime", "ONNX Runtime (faster-whisper's, the whisper extra)")
    session = onnxruntime.InferenceSession(str(silero.MODEL), providers=["CPUExecutionProvider"])
    audio = np.concatenate([samples, np.random.default_rng(1).normal(0, 0.05, SAMPLE_RATE).astype(np.float32)])
    n = len(audio) // WINDOW
    frames = audio[: n * WINDOW].reshape(n, WINDOW)
    inputs = np.hstack([np.concatenate([np.zeros((1, CONTEXT), np.float32), frames[:-1, -CONTEXT:]]), frames])
    zeros = np.zeros((1, 1, silero.HIDDEN), np.float32)
    expected, h, c = session.run(None, {"input": inputs, "h": zeros, "c": zeros})
    (got,), (state,) = silero.network().probabilities([inputs], [np.zeros((2, silero.HIDDEN), np.float32)])
    assert expected.max() > 0.9 and expected.min() < 0.1
    np.testing.assert_allclose(got, expected.reshape(-1), atol=1e-5)
    np.testing.assert_allclose(state, np.concatenate([h, c]).reshape(2, -1), atol=1e-4)


def test_detectors_pushed_together_give_what_each_gives_alone(samples):
    """push_together runs the windows of several detectors in one call of the network, whatever
    each one's pieces (a detector with no window in a call, or several): each gets its own."""
    calls = []
    network = silero.network()
    signals = [samples, samples[::-1].copy(), samples[4000:], np.zeros(20000, np.float32)]
    alone, together = [VoiceActivity() for _ in signals], [VoiceActivity() for _ in signals]
    rng = np.random.default_rng(7)
    at, got, expected = [0] * 4, [[] for _ in signals], [[] for _ in signals]
    while any(a < len(x) for a, x in zip(at, signals)):
        chunks = []
        for k, x in enumerate(signals):
            n = int(rng.integers(0, 3 * WINDOW))
            chunks.append(x[at[k]:at[k] + n])
            at[k] += n
        probabilities = network.probabilities
        network.probabilities = lambda *args: calls.append(1) or probabilities(*args)
        try:
            results = VoiceActivity.push_together(together, chunks)
        finally:
            del network.probabilities
        assert len(calls) <= 1
        calls.clear()
        for k, (detector, chunk) in enumerate(zip(alone, chunks)):
            expected[k].append(detector.push(chunk))
            got[k].append(results[k])
    for k in range(len(signals)):
        np.testing.assert_allclose(np.concatenate(got[k]), np.concatenate(expected[k]), atol=1e-6)
        np.testing.assert_array_equal(together[k].spans, alone[k].spans)
    assert len(together[0].spans) == 1 and len(together[3].spans) == 0


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
    monkeypatch.setattr("vispeech.frontends.vad.SAMPLE_RATE", 0)  # a detector for no network's rate: none
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


def test_live_streams_pushed_together_rest_as_each_does_alone(samples):
    """push_audio_together with voice activity: the detectors of all the streams run in one call,
    the rest of all their frames is weighed in one call, and every stream gets the frames, rest
    included, it gets pushed alone, whenever it began and wherever its speech and silences lie."""
    audio = np.concatenate([samples, np.zeros(int(GAP * SAMPLE_RATE), np.float32), samples[: SAMPLE_RATE]])
    late = np.concatenate([np.zeros(SAMPLE_RATE, np.float32), samples[SAMPLE_RATE:]])
    pcm = [(x * 32767).astype("<i2").tobytes() for x in (audio, samples[::-1], late)]
    model = load_model(DEFAULT_AUDIO_STREAM_MODEL)
    plans = [[640] * (len(pcm[0]) // 640 + 1), list(np.random.default_rng(2).integers(1, 2000, 200) * 2)]
    plans.append([960] * (len(pcm[2]) // 960 + 1))
    starts = [0, 0, 40]  # the third stream begins 40 ticks later
    chunks: list[list[bytes]] = [[], [], []]
    for k, sizes in enumerate(plans):
        ends = np.cumsum([0, *sizes])
        chunks[k] = [pcm[k][a:b] for a, b in zip(ends[:-1], ends[1:]) if a < len(pcm[k])]
    alone = []
    for k in range(3):
        stream = LiveAudioStream(model, SAMPLE_RATE, 30.0)
        alone.append(np.concatenate([*(stream.push(c)[1] for c in chunks[k]), stream.finish()[1]]))
    streams = [LiveAudioStream(model, SAMPLE_RATE, 30.0) for _ in range(3)]
    together: list[list[np.ndarray]] = [[], [], []]
    for tick in range(max(start + len(c) for start, c in zip(starts, chunks))):
        due = [k for k in range(3) if 0 <= tick - starts[k] < len(chunks[k])]
        pushes = [(streams[k], chunks[k][tick - starts[k]]) for k in due]
        for k, (_, rows) in zip(due, push_audio_together(pushes)):
            together[k].append(rows)
    for k, stream in enumerate(streams):
        np.testing.assert_allclose(np.concatenate([*together[k], stream.finish()[1]]), alone[k], atol=1e-6)
        assert stream.activity is not None and len(stream.activity.spans)
