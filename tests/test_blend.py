"""Audio and phones together (issue 22): an audio model's frames blended with the phone model's
when the transcript is known, and which model animates a recording by default."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED, require
from vispeech.frontends.audio import AudioClip
from vispeech.models.registry import load_model
from vispeech.motion.track import Track
from vispeech.pipeline import (
    DEFAULT_AUDIO_MODEL,
    DEFAULT_MODEL,
    WHISPER_AUDIO_MODEL,
    WHISPER_ENSEMBLE_MODEL,
    WHISPER_SWEDISH_MODEL,
    animate_audio,
    blend_with_phones,
    default_audio_model,
    hear,
    recording_model,
    speech_spans,
)
from vispeech.postprocess import PostprocessConfig, postprocess

GRID_CLIP = SHARED / "data" / "grid_s1" / "utterances" / "bbaf2n.flac"
GRID_TEXT = "bin blue at f two now"


def test_blend_mixes_the_shared_channels_and_keeps_the_audio_models_others():
    audio = Track(np.full((4, 2), 0.8), ("jawOpen", "tongueOut"), 30.0, 0.5)
    phones = Track(np.full((4, 2), 0.2), ("jawOpen", "mouthClose"), 30.0, 0.5)
    blended = blend_with_phones(audio, phones, 0.75)
    assert blended.channels == audio.channels and blended.start_time == 0.5
    assert np.allclose(blended["jawOpen"], 0.75 * 0.8 + 0.25 * 0.2)
    assert np.allclose(blended["tongueOut"], 0.8)
    assert np.allclose(audio.values, 0.8)  # the input is left as it was
    with pytest.raises(ValueError, match="differ in length"):
        blend_with_phones(audio, Track(np.zeros((3, 1)), ("jawOpen",), 30.0))


def test_the_default_for_a_recording_follows_the_transcript_its_language_and_whisper(monkeypatch):
    import vispeech.frontends.whisper as whisper

    monkeypatch.delenv(whisper.MODEL_ENV, raising=False)
    monkeypatch.setattr(whisper, "installed", lambda model="whisper-tiny.en": True)
    # both Whisper models: their ensemble hears audio in every language; tiny.en with an English transcript
    assert recording_model(False) == default_audio_model() == WHISPER_ENSEMBLE_MODEL
    assert recording_model(False, "sv") == recording_model(False, "de") == WHISPER_ENSEMBLE_MODEL
    assert recording_model(True, "en") == WHISPER_AUDIO_MODEL
    assert recording_model(True, "sv") == DEFAULT_MODEL  # Swedish transcripts: the phone model on their phones
    # one Whisper folder in place of both: Swedish audio takes the model on Whisper base, which heard
    # Swedish, and any other language tiny.en's
    monkeypatch.setenv(whisper.MODEL_ENV, "/somewhere/whisper")
    assert recording_model(False, "sv") == default_audio_model("sv") == WHISPER_SWEDISH_MODEL
    assert recording_model(False, "de") == recording_model(False, "en") == recording_model(True, "en") == WHISPER_AUDIO_MODEL
    monkeypatch.delenv(whisper.MODEL_ENV)
    # tiny.en without base's packages: Swedish audio takes tiny.en rather than a model that cannot run
    monkeypatch.setattr(whisper, "installed", lambda model="whisper-tiny.en": model == "whisper-tiny.en")
    assert recording_model(False, "sv") == recording_model(True, "en") == WHISPER_AUDIO_MODEL
    monkeypatch.setattr(whisper, "installed", lambda model="whisper-tiny.en": False)
    assert recording_model(True, "en") == DEFAULT_MODEL
    assert recording_model(False) == default_audio_model() == recording_model(False, "sv") == DEFAULT_AUDIO_MODEL


def test_an_audio_model_with_the_transcript_animates_the_blend_closed_on_its_bilabials():
    """grid-audio-encdec (core) on a GRID clip with its aligned transcript: the post-processed
    blend of its frames and grid-tdnn's, the lips shut on the aligned /b/ of 'bin'."""
    require(GRID_CLIP.is_file(), f"grid_s1 ({GRID_CLIP})")
    clip = AudioClip.read(GRID_CLIP)
    phones = hear(clip, GRID_TEXT).phones
    assert phones is not None
    model = load_model("grid-audio-encdec")
    track = animate_audio(clip, model, 30.0, phones=phones)
    n = clip.n_frames(30.0)
    said = load_model(DEFAULT_MODEL).predict(phones, 30.0).resample(30.0, n_frames=n)
    raw = blend_with_phones(model.predict(clip, 30.0), said)
    config = PostprocessConfig.from_preset("audio-closures")
    assert np.allclose(track.values, postprocess(raw, phones, config, speech=speech_spans(clip)).values)
    audio_only = animate_audio(clip, model, 30.0)
    assert not np.allclose(track["jawOpen"], audio_only["jawOpen"])
    b = next(p for p in phones if p.symbol == "B")
    middle = int(round((b.start + b.end) / 2 * 30.0))
    assert track["mouthClose"][middle] >= 0.9 * track["jawOpen"][middle] > 0


def test_the_pipeline_names_what_it_takes_when_given_something_else():
    """``animate(clip)``, ``animate_audio(phones)``, ``listen(array)`` and ``hear("x.wav")`` died of
    AttributeErrors deep inside ('AudioClip' object has no attribute 'validate', ...)."""
    from vispeech import VispeechError
    from vispeech.pipeline import animate, animate_many, listen, utter

    clip = AudioClip.from_array(np.zeros(16000, np.float32), 16000)
    phones = utter("Hello").phones
    for call, message in ((lambda: animate(clip), "^animate takes phones .*, not AudioClip$"),
                          (lambda: animate_audio(phones), "^animate_audio takes audio .*, not PhoneSequence$"),
                          (lambda: listen(np.zeros(16000)), "^a recording is audio .*, not ndarray$"),
                          (lambda: hear("x.wav"), "^a recording is audio .*, not str$")):
        with pytest.raises(VispeechError, match=message):
            call()
    (refused,) = animate_many([clip])
    assert isinstance(refused, VispeechError) and "animate_many takes phones" in str(refused)
