"""The mouth at rest before and after speech (issue 26): the rest-in-silence step of
post-processing, and every shipped model's first and last frames on text, on audio and in streams."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import SHARED, require
from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.models.registry import RUNNABLE, load_model
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.motion.track import Track
from vispeech.pipeline import LEADING_SILENCE, TRAILING_SILENCE, animate_audio, speak, speech_spans
from vispeech.postprocess import PostprocessConfig, postprocess
from vispeech.postprocess.rest import EASE, HOLD, REST_CHANNELS, rest_weights, speech_intervals

REST_LEVEL = 0.05
"""A channel at or below this is at rest: the GRID speaker's jawOpen in silence is 0.02 (90th
percentile 0.043) and lips at or below :data:`LIP_CLOSED` aperture are closed."""
TEXT = "Hello, how can I help you today?"
GRID_CLIP = SHARED / "data" / "grid_s1" / "utterances" / "bbaf2n.flac"
"""'bin blue at f two now', its first word 0.95 s in."""


def at_rest(track: Track, frame: int) -> bool:
    """Whether frame ``frame`` of ``track`` shows the mouth at rest: jaw, lips and tongue at most
    :data:`REST_LEVEL`, the lips closed."""
    pose = Track(track.values[[frame]], track.channels, track.fps)
    mouth = [c for c in REST_CHANNELS if c in track.channels]
    return bool(pose.select(mouth).values.max() <= REST_LEVEL and lip_aperture(pose)[0] <= LIP_CLOSED)


def near_speech(track: Track, speech: np.ndarray) -> np.ndarray:
    """Frames within :data:`HOLD` of speech: where the rest must not change the model's motion."""
    times = track.start_time + np.arange(track.n_frames) / track.fps
    return np.array([((speech[:, 0] - HOLD <= t) & (t <= speech[:, 1] + HOLD)).any() for t in times])


# -- the step ------------------------------------------------------------------------------------

def test_rest_weights_hold_near_speech_and_ease_to_rest_beyond():
    speech = np.array([[1.0, 2.0], [2.2, 3.0]])
    times = np.arange(0, 4.0, 0.01)
    w = rest_weights(times, speech)
    eps = 1e-9  # times a rounding error off the edges
    assert w[(times > 1.0 - HOLD + eps) & (times < 3.0 + HOLD - eps)].max() < 1e-12  # a pause of 2 HOLD: no rest
    assert np.all(w[(times < 1.0 - HOLD - EASE - eps) | (times > 3.0 + HOLD + EASE + eps)] == 1)
    rising = (times > 3.0 + HOLD) & (times < 3.0 + HOLD + EASE)
    assert np.all(np.diff(w[rising]) > 0) and w[rising].min() > 0 and w[rising].max() < 1
    np.testing.assert_allclose(rest_weights(np.array([3.0 + HOLD + EASE / 2]), speech), [0.5])
    assert rest_weights(times, speech_intervals([])).tolist() == [1.0] * len(times)
    long_pause = rest_weights(np.array([5.0]), np.array([[1.0, 2.0], [8.0, 9.0]]))
    assert long_pause.tolist() == [1.0]


def test_speech_is_where_phones_are_not_silence_merged():
    phones = PhoneSequence([Phone("sil", 0.0, 0.5), Phone("HH", 0.5, 0.6), Phone("AY", 0.6, 0.9),
                            Phone("sil", 0.9, 1.4), Phone("B", 1.4, 1.5), Phone("sil", 1.5, 2.0)], "en")
    assert speech_intervals(phones).tolist() == [[0.5, 0.9], [1.4, 1.5]]
    assert speech_intervals([(1.0, 2.0), (0.0, 0.5), (0.4, 0.6)]).tolist() == [[0.0, 0.6], [1.0, 2.0]]


def test_the_rest_changes_only_the_mouth_and_only_in_silence():
    phones = PhoneSequence([Phone("sil", 0.0, 0.6), Phone("AA", 0.6, 0.9, None, 1), Phone("sil", 0.9, 1.5)], "en")
    channels = ("jawOpen", "mouthClose", "mouthFunnel", "tongueTipUp", "eyeBlinkLeft", "browInnerUp")
    track = Track(np.full((45, len(channels)), 0.3), channels, 30.0)
    config = replace(PostprocessConfig.from_preset("audio"), close_within_jaw=False)
    rested = postprocess(track, phones, config)
    kept = postprocess(track, phones, replace(config, rest=False))
    mouth = [channels.index(c) for c in channels[:4]]
    near = near_speech(track, speech_intervals(phones))
    assert np.array_equal(rested.values[near], kept.values[near])
    assert np.array_equal(rested.values[:, 4:], kept.values[:, 4:])  # eyes and brows as they were
    assert rested.values[[0, -1]][:, mouth].max() == 0.0 and at_rest(rested, 0) and at_rest(rested, -1)
    assert np.all(np.diff(rested["jawOpen"][:18]) >= 0)  # it opens towards the vowel


def test_without_phones_the_rest_needs_the_speech_spans():
    track = Track(np.full((30, 2), 0.4), ("jawOpen", "mouthClose"), 30.0)
    with pytest.raises(VispeechError, match="at rest in silence needs phones or the speech spans"):
        postprocess(track, None, PostprocessConfig.from_preset("audio"))
    assert postprocess(track, None, PostprocessConfig.from_preset("audio"), speech=[]).values.max() == 0
    spoken = postprocess(track, None, PostprocessConfig.from_preset("audio"), speech=[(0.4, 0.6)])
    assert spoken["jawOpen"][12:18].min() == pytest.approx(0.4) and spoken["jawOpen"][[0, -1]].max() == 0


# -- every shipped model ---------------------------------------------------------------------------

PHONE_MODELS = [name for name in RUNNABLE if load_model(name).input_kind == "phones"]
AUDIO_MODELS = [name for name in RUNNABLE if name not in PHONE_MODELS]


@pytest.mark.parametrize("model", PHONE_MODELS)
@pytest.mark.parametrize(("lang", "text"), [("en", TEXT), ("sv", "Mamma och pappa bor på Möllevången i Malmö.")])
def test_text_starts_and_ends_at_rest_with_the_models_motion_kept_near_speech(model, lang, text):
    """speak() puts LEADING_SILENCE before espeak-ng's speech and TRAILING_SILENCE after it: the
    first and last frames are at rest, and frames within HOLD of speech are the model's own."""
    utterance = speak(text, lang, model=model)
    track = utterance.track
    first, last = utterance.phones.phones[0], utterance.phones.phones[-1]
    half_sample = 0.5 / utterance.sample_rate
    assert first.is_silence and first.end >= LEADING_SILENCE - half_sample
    assert last.is_silence and last.duration >= TRAILING_SILENCE - half_sample
    assert at_rest(track, 0) and at_rest(track, -1), model
    config = PostprocessConfig.from_preset(load_model(model).postprocessing)
    kept = speak(text, lang, model=model, postprocessing=replace(config, rest=False)).track
    near = near_speech(track, speech_intervals(utterance.phones))
    assert np.array_equal(track.values[near], kept.values[near])
    assert lip_aperture(track)[near].max() > 0.1  # it still speaks


@pytest.fixture(scope="module")
def grid_clip() -> AudioClip:
    require(GRID_CLIP.is_file(), f"grid_s1 ({GRID_CLIP})")
    return AudioClip.read(GRID_CLIP)


@pytest.mark.parametrize("model", AUDIO_MODELS)
def test_audio_starts_and_ends_at_rest_and_keeps_the_breath_in(model, grid_clip):
    """A GRID clip (0.95 s of silence before 'bin' by the corpus's timing): the first and last
    frames at rest; every frame within HOLD of the audio's loud span, which starts with the breath
    before the first word, is the model's own."""
    (span,) = speech_spans(grid_clip)
    assert span[0] < 0.95 - 0.2  # the breath in is loud enough to count as speech
    track = animate_audio(grid_clip, model, 30.0)
    assert at_rest(track, 0) and at_rest(track, -1), model
    estimator = load_model(model)
    raw, heard = estimator.predict_with_closures(grid_clip, 30.0)
    preset = estimator.postprocessing if heard is None else "audio-closures"
    kept = postprocess(raw, heard, replace(PostprocessConfig.from_preset(preset), rest=False), speech=[span])
    near = near_speech(track, np.array([span]))
    assert np.array_equal(track.values[near], kept.values[near])
    before = np.flatnonzero(near)[0]
    assert track["jawOpen"][before:round(0.95 * 30)].max() > REST_LEVEL  # open before 'bin'


def test_a_text_stream_starts_and_ends_at_rest():
    from vispeech.text_stream import speech_messages

    model = load_model("grid-tdnn-lowlatency")
    messages = [m for batch in speech_messages(TEXT, "en", model) for m in batch]
    channels = messages[0]["channels"]
    frames = np.array([row for m in messages if m["type"] == "frames" for row in m["frames"]])
    track = Track(frames, tuple(channels), messages[0]["fps"])
    assert at_rest(track, 0) and at_rest(track, -1)


def test_the_loudness_span_covers_the_words_it_misses_the_edges_of():
    """Loudness misses a first stop's silent closure and a fading last sound: on grid_s1's
    validation split the span with its margins covers every word of 90 or more of the 100
    utterances (the bare loudness span: 16)."""
    from vispeech.corpus.grid import read_grid

    folder = SHARED / "data" / "grid_s1"
    require(folder.is_dir(), f"grid_s1 ({folder})")
    covered = 0
    for utterance in read_grid(folder).split("validation"):
        (start, end), = speech_spans(AudioClip.from_array(*utterance.load_audio()))
        covered += start <= utterance.words[0].start and end >= utterance.words[-1].end
    assert covered >= 90
