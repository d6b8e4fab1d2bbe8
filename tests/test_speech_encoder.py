"""The optional pretrained speech encoder: tiny random WavLM / wav2vec 2.0 folders made here
(nothing downloaded), hidden states and their framing, chunking, errors, and audio networks
that read them through the learned layer fusion (NumPy equals torch, save/load, stream, CLI)."""

import json
import math
import shutil
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import require_module

torch = require_module("torch", 'torch (pip install "vispeech[encoder]")')
transformers = require_module("transformers", 'transformers (pip install "vispeech[encoder]")')

from test_audio_networks import synthetic_utterance, torch_outputs  # noqa: E402
from test_train_cli import write_takes  # noqa: E402

from vispeech import VispeechError  # noqa: E402
from vispeech.cli import main  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.frontends.encoder import SpeechEncoder  # noqa: E402
from vispeech.models.fitting import Splits  # noqa: E402
from vispeech.models.networks.audio import AUDIO_PARAMS, AudioCNNNetwork, EncoderDecoderNetwork  # noqa: E402
from vispeech.models.registry import load_model  # noqa: E402

RATE = 16000
TINY_ENCODER = {"hidden_size": 32, "num_hidden_layers": 2, "num_attention_heads": 2, "intermediate_size": 64,
                "conv_dim": (32,) * 7, "num_conv_pos_embeddings": 16, "num_conv_pos_embedding_groups": 2}
"""Three hidden states of 32 values; the standard 7-layer front end (25 ms window, 20 ms stride)."""
TINY_NETWORK = {"features": "encoder", "targets": ["jawOpen", "mouthFunnel"], "channels": [8, 8, 8], "epochs": 6,
                "patience": 6, "learning_rate": 3e-3, "batch_size": 4, "seed": 0}


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")


@pytest.fixture(scope="module")
def wavlm(tmp_path_factory) -> str:
    """A random WavLM (group-normed front end, as the base models) without a feature extractor config."""
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("wavlm")
    transformers.WavLMModel(transformers.WavLMConfig(**TINY_ENCODER)).save_pretrained(folder)
    return str(folder)


@pytest.fixture(scope="module")
def wav2vec2(tmp_path_factory) -> str:
    """A random wav2vec 2.0 with a layer-normed front end (as the large models) and do_normalize."""
    torch.manual_seed(1)
    folder = tmp_path_factory.mktemp("wav2vec2")
    config = transformers.Wav2Vec2Config(**TINY_ENCODER, feat_extract_norm="layer", conv_bias=True)
    transformers.Wav2Vec2Model(config).save_pretrained(folder)
    (folder / "preprocessor_config.json").write_text(json.dumps({"do_normalize": True, "sampling_rate": 16000}))
    return str(folder)


def speech_like(seconds: float, seed: int = 0) -> AudioClip:
    """A buzz whose loudness swings three times a second, with a little noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * RATE)) / RATE
    buzz = np.sin(2 * np.pi * 150 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 3 * t))
    return AudioClip.from_array((0.3 * buzz + 0.01 * rng.normal(size=len(t))).astype(np.float32), RATE)


# -- the encoder ---------------------------------------------------------------------------

@pytest.mark.parametrize("fixture", ["wavlm", "wav2vec2"])
def test_hidden_states_come_at_50_fps_for_every_layer(fixture, request):
    encoder = SpeechEncoder.load(request.getfixturevalue(fixture))
    assert (encoder.layers, encoder.width, encoder.stride, encoder.receptive) == (3, 32, 320, 400)
    assert encoder.normalize == (fixture == "wav2vec2")
    for seconds in (0.001, 0.02, 0.3, 1.0, 1.234, 2.5):
        clip = speech_like(seconds)
        states = encoder.hidden_states(clip)
        assert states.shape == (3, math.ceil(seconds * 50), 32) and states.dtype == np.float32
        assert np.isfinite(states).all()
    # other sample rates are resampled to the encoder's: the frame grid stays at 50 fps
    clip = speech_like(1.234)
    at_8k = AudioClip.from_array(clip.resampled(8000).samples, 8000)
    assert encoder.hidden_states(at_8k).shape == (3, 62, 32)


def test_loaded_encoders_are_shared_per_folder(wavlm, monkeypatch, tmp_path):
    assert SpeechEncoder.load(wavlm) is SpeechEncoder.load(wavlm + "/")
    monkeypatch.chdir(wavlm)
    assert SpeechEncoder.load(".") is SpeechEncoder.load(wavlm)


@pytest.mark.parametrize(("fixture", "tolerance"), [("wav2vec2", 0.01), ("wavlm", 0.15)])
def test_chunked_audio_follows_one_pass(fixture, tolerance, request):
    """Chunks of 1 s with 1 s of context either side, against one pass over 4 s: nearly equal
    with a layer-normed front end; within a few percent with a group-normed one (its
    normalisation sees the chunk's audio)."""
    encoder = SpeechEncoder.load(request.getfixturevalue(fixture))
    clip = speech_like(4.0)
    whole = encoder.hidden_states(clip)
    chunked = encoder.hidden_states(clip, chunk=1.0, overlap=1.0)
    assert chunked.shape == whole.shape
    for layer in range(3):
        assert np.abs(chunked[layer] - whole[layer]).max() < tolerance * whole[layer].std()


def test_encoder_errors_are_one_line(tmp_path, wavlm, monkeypatch):
    with pytest.raises(VispeechError, match="speech encoder folder not found"):
        SpeechEncoder.load(tmp_path / "nowhere")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(VispeechError, match="has no config.json"):
        SpeechEncoder.load(empty)
    bert = tmp_path / "bert"
    bert.mkdir()
    (bert / "config.json").write_text(json.dumps({"model_type": "bert"}))
    with pytest.raises(VispeechError, match="'bert' model; vispeech reads wav2vec2, wavlm, hubert"):
        SpeechEncoder.load(bert)
    (bert / "config.json").write_text("{not json")
    with pytest.raises(VispeechError, match="cannot read"):
        SpeechEncoder.load(bert)
    no_weights = tmp_path / "no-weights"
    no_weights.mkdir()
    shutil.copy(f"{wavlm}/config.json", no_weights)
    with pytest.raises(VispeechError, match="cannot load speech encoder"):
        SpeechEncoder.load(no_weights)
    copy = shutil.copytree(wavlm, tmp_path / "copy")
    monkeypatch.setitem(sys.modules, "transformers", None)  # as if not installed
    with pytest.raises(VispeechError, match=r'pip install "vispeech\[encoder\]"') as error:
        SpeechEncoder.load(copy)
    assert "\n" not in str(error.value)


# -- audio networks on the encoder ---------------------------------------------------------

@pytest.fixture(scope="module")
def corpus() -> Splits:
    rng = np.random.default_rng(0)
    return Splits([synthetic_utterance(rng, i) for i in range(8)], [synthetic_utterance(rng, 50 + i) for i in range(2)])


@pytest.fixture(scope="module")
def cnn(corpus, wavlm) -> AudioCNNNetwork:
    return AudioCNNNetwork(**TINY_NETWORK, encoder=wavlm, velocity_weight=0.5).fit(corpus, progress=False)


@pytest.fixture(scope="module")
def encdec(corpus, wav2vec2) -> EncoderDecoderNetwork:
    return EncoderDecoderNetwork(**{**TINY_NETWORK, "epochs": 2, "channels": [8]}, kernels=[5], hidden=4, layers=1,
                                 encoder=wav2vec2, ctc_weight=0.01).fit(corpus, progress=False)


def clip_of(utterance) -> AudioClip:
    return AudioClip.from_array(utterance.audio, utterance.sample_rate)


def test_the_network_learns_a_fusion_of_every_layer(cnn, wavlm):
    encoding = cnn.encoding_
    assert (encoding.kind, encoding.encoder, encoding.layers, encoding.width) == ("encoder", wavlm, 3, 32)
    assert encoding.fps == 50 and encoding.normalize == "global" and len(encoding.mean) == len(encoding.std) == 96
    logits = cnn.weights_["fusion.logits"]
    assert logits.shape == (3,) and not np.allclose(logits, 0)  # learned from the zeros it starts at
    weights = torch.softmax(torch.from_numpy(logits), dim=0).numpy()
    assert weights.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(cnn.kernel.fusion.weights, weights, atol=1e-6)
    assert cnn.weights_["encoder.convs.0.weight"].shape[1] == 32  # the convolutions read the fused width
    assert cnn.history_.train_loss[-1] < cnn.history_.train_loss[0]
    assert not hasattr(cnn, "_hidden")  # the training cache goes with fit


@pytest.mark.parametrize("fixture", ["cnn", "encdec"])
def test_numpy_inference_equals_torch(fixture, request):
    model = request.getfixturevalue(fixture)
    x = np.random.default_rng(3).normal(size=(41, model.encoding_.size)).astype(np.float32)
    np.testing.assert_allclose(model.kernel.forward(x), torch_outputs(model, x), atol=1e-5)


@pytest.mark.parametrize("fixture", ["cnn", "encdec"])
def test_save_load_predicts_identically_without_the_corpus(fixture, request, tmp_path):
    model = request.getfixturevalue(fixture)
    folder = model.save(tmp_path / "model")
    loaded = load_model(folder)
    assert loaded.get_params() == model.get_params() and loaded.encoding_ == model.encoding_
    clip = speech_like(1.7, seed=5)
    track = loaded.predict(clip, 30)
    assert track.n_frames == clip.n_frames(30) and np.isfinite(track.values).all()
    np.testing.assert_array_equal(track.values, model.predict(clip, 30).values)


def test_encoder_stream_follows_the_offline_prediction(cnn, corpus):
    clip = clip_of(corpus.validation[0])
    offline = cnn.predict(clip, 25).values
    stream = cnn.stream(None, 25)
    ahead, step = AUDIO_PARAMS["encoder_ahead"], AUDIO_PARAMS["encoder_step"]  # 0.2 s, 0.2 s
    assert stream.delay == pytest.approx(8 / 50 + ahead + step)
    parts, given = [], 0
    for i in range(0, len(clip.samples), 320):
        start, frames = stream.push(clip.samples[i:i + 320])
        assert start == given
        given += len(frames)
        heard = min(len(clip.samples), i + 320) / RATE
        # no frame before the look-ahead and encoder_ahead of audio follow it; none later than delay
        assert given <= max(0, math.floor((heard - stream.delay + step) * 25 + 1e-6) + 1)
        assert given >= math.floor((heard - stream.delay) * 25) - 1
        parts.append(frames)
    parts.append(stream.finish()[1])
    streamed = np.concatenate(parts)
    assert streamed.shape == offline.shape
    # approximate: the first re-encodings hear a few hundred ms, the offline pass the whole clip
    assert np.abs(streamed - offline).mean() < 0.05
    assert np.corrcoef(streamed[:, 0], offline[:, 0])[0, 1] > 0.95


def test_encoder_parameters_are_checked(wavlm):
    with pytest.raises(VispeechError, match="features=encoder needs encoder=FOLDER"):
        AudioCNNNetwork(features="encoder")
    with pytest.raises(VispeechError, match="encoder= needs features=encoder"):
        AudioCNNNetwork(encoder=wavlm)
    with pytest.raises(VispeechError, match="50 fps"):
        AudioCNNNetwork(features="encoder", encoder=wavlm, fps=25.0)
    untrained = AudioCNNNetwork(features="encoder", encoder="/no/such/encoder", targets=["jawOpen"])  # checked in use
    with pytest.raises(VispeechError, match="speech encoder folder not found"):
        untrained.fit(Splits([synthetic_utterance(np.random.default_rng(0), 0)], []), progress=False)


def test_vispeech_train_takes_encoder_parameters(tmp_path, wavlm, monkeypatch):
    monkeypatch.setenv("VISPEECH_CACHE", str(tmp_path / "cache-home"))
    takes = write_takes(tmp_path / "takes", [f"u{i:02d}" for i in range(6)])
    out = tmp_path / "wavlm-cnn"
    result = CliRunner().invoke(main, ["train", "--corpus", str(takes), "--model", "audio-cnn", "--epochs", "1", "-q",
                                       "--param", "features=encoder", "--param", f"encoder={wavlm}",
                                       "--param", "channels=[4, 4, 4]", "-o", str(out)])
    assert result.exit_code == 0, result.output
    model = load_model(out)
    assert model.get_params()["encoder"] == wavlm and model.get_params()["channels"] == [4, 4, 4]
    assert model.weights_["fusion.logits"].shape == (3,)
    for bad, message in ((["--param", "widht=3"], "takes no parameter 'widht'"),
                         (["--param", "epochs=2"], "epochs is given twice"),
                         (["--param", "features"], "KEY=VALUE")):
        result = CliRunner().invoke(main, ["train", "--corpus", str(takes), "--model", "audio-cnn", "--epochs", "1",
                                           *bad, "-o", str(tmp_path / "bad")])
        assert result.exit_code != 0 and message in result.output, result.output
