"""The audio networks: learning, NumPy inference against torch, streaming, save/load, CTC, errors."""

import copy
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torch")

import torch  # noqa: E402

from vispeech import VispeechError  # noqa: E402
from vispeech.alignment.phones import Phone, PhoneSequence  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.models.fitting import Splits  # noqa: E402
from vispeech.models.networks.audio import AudioCNNNetwork, EncoderDecoderNetwork  # noqa: E402
from vispeech.models.registry import create_model, load_model  # noqa: E402
from vispeech.motion.track import Track  # noqa: E402
from vispeech.utterance import Utterance  # noqa: E402

RATE = 16000
SYMBOLS = ["AA", "IY", "M", "S", "T", "AE"]


def synthetic_utterance(rng: np.random.Generator, index: int) -> Utterance:
    """A buzz whose loudness follows the 'jaw': vowels loud and open, consonants quiet and closed."""
    phones, t = [Phone("sil", 0.0, 0.3)], 0.3
    for symbol in rng.choice(SYMBOLS, 6):
        d = float(rng.uniform(0.08, 0.2))
        phones.append(Phone(str(symbol), t, t + d))
        t += d
    phones.append(Phone("sil", t, t + 0.3))
    sequence = PhoneSequence(phones, "en").validate()
    n = int(sequence.duration * RATE)
    times = np.arange(n) / RATE
    open_ = np.zeros(n)
    for p in phones:
        if p.symbol in ("AA", "IY", "AE"):
            open_[(times >= p.start) & (times < p.end)] = 1.0 if p.symbol == "AA" else 0.6
    smooth = np.convolve(open_, np.hanning(800) / np.hanning(800).sum(), mode="same")
    f0 = 110 + 10 * index % 30
    buzz = sum(np.sin(2 * np.pi * f0 * k * times) / k for k in range(1, 20))
    audio = (0.3 * smooth * buzz / 3 + 0.002 * rng.normal(size=n)).astype(np.float32)
    frames = sequence.n_frames(25)
    jaw = np.interp(np.arange(frames) / 25, times, smooth)
    track = Track(np.column_stack([jaw, 0.2 * jaw]), ("jawOpen", "mouthFunnel"), 25.0)
    return Utterance(id=f"u{index}", phones=sequence, track=track, audio=audio, sample_rate=RATE)


@pytest.fixture(scope="module")
def corpus() -> Splits:
    rng = np.random.default_rng(0)
    return Splits([synthetic_utterance(rng, i) for i in range(10)], [synthetic_utterance(rng, 50 + i) for i in range(2)])


@pytest.fixture(scope="module")
def held_out() -> list:
    rng = np.random.default_rng(1)
    return [synthetic_utterance(rng, 100 + i) for i in range(3)]


TINY = {"targets": ["jawOpen", "mouthFunnel"], "n_mels": 24, "pitch_copies": 0, "epochs": 25, "patience": 25,
        "learning_rate": 3e-3, "batch_size": 4, "seed": 0}


@pytest.fixture(scope="module")
def cnn(corpus) -> AudioCNNNetwork:
    return AudioCNNNetwork(**TINY, channels=[16, 16, 16], velocity_weight=0.5, acceleration_weight=0.5).fit(
        corpus, progress=False)


@pytest.fixture(scope="module")
def recurrent_cnn(corpus) -> AudioCNNNetwork:
    """The CNN with a forward GRU over its convolutions and a CTC head."""
    return AudioCNNNetwork(**{**TINY, "epochs": 12}, channels=[16, 16, 16], look_ahead=2, recurrent=8,
                           ctc_weight=0.01).fit(corpus, progress=False)


@pytest.fixture(scope="module")
def encdec(corpus) -> EncoderDecoderNetwork:
    return EncoderDecoderNetwork(**{**TINY, "epochs": 12}, channels=[16, 16], hidden=8, ctc_weight=0.01).fit(
        corpus, progress=False)


def clip_of(utterance: Utterance) -> AudioClip:
    return AudioClip.from_array(utterance.audio, utterance.sample_rate)


def jaw_error_ratio(model, corpus, held_out) -> float:
    mean = np.mean(np.concatenate([u.track["jawOpen"] for u in corpus.train]))
    errors, baseline = [], []
    for u in held_out:
        predicted = model.predict(clip_of(u), 25)["jawOpen"]
        errors.append(np.mean((predicted - u.track["jawOpen"]) ** 2))
        baseline.append(np.mean((mean - u.track["jawOpen"]) ** 2))
    return float(np.mean(errors) / np.mean(baseline))


@pytest.mark.parametrize("fixture", ["cnn", "encdec"])
def test_audio_networks_learn_the_jaw_from_loudness(fixture, request, corpus, held_out):
    model = request.getfixturevalue(fixture)
    assert model.input_kind == "audio" and model.postprocessing == "audio"
    assert jaw_error_ratio(model, corpus, held_out) < 0.5
    track = model.predict(clip_of(held_out[0]), 30)
    assert track.n_frames == clip_of(held_out[0]).n_frames(30) and track.channels == ("jawOpen", "mouthFunnel")
    assert np.all((track.values >= 0) & (track.values <= 1))


def torch_outputs(model, inputs: np.ndarray) -> np.ndarray:
    """What the fitted audio network's torch module gives for one utterance's input rows."""
    module = model._build_module(model.encoding_.size, len(model.outputs_))
    module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in model.weights_.items()})
    module.eval()
    with torch.no_grad():
        return module(torch.from_numpy(inputs[None]), torch.tensor([len(inputs)]))[0][0].numpy()


@pytest.mark.parametrize("fixture", ["cnn", "recurrent_cnn", "encdec"])
def test_numpy_inference_equals_torch(fixture, request):
    model = request.getfixturevalue(fixture)
    x = np.random.default_rng(3).normal(size=(57, model.encoding_.size)).astype(np.float32)
    np.testing.assert_allclose(model.kernel.forward(x), torch_outputs(model, x), atol=2e-5)


def test_numpy_phone_posteriors_equal_torch(encdec, cnn):
    x = np.random.default_rng(4).normal(size=(41, encdec.encoding_.size)).astype(np.float32)
    module = encdec._build_module(encdec.encoding_.size, len(encdec.outputs_))
    module.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in encdec.weights_.items()})
    module.eval()
    with torch.no_grad():
        logits = module(torch.from_numpy(x[None]), torch.tensor([len(x)]))[1][0]
    outputs, posteriors = encdec.kernel.forward_with_phones(x)
    np.testing.assert_allclose(posteriors, torch.softmax(logits.double(), -1).numpy(), atol=1e-5)
    np.testing.assert_array_equal(outputs, encdec.kernel.forward(x))
    assert posteriors.shape == (41, len(encdec.phones_) + 1)
    assert cnn.kernel.forward_with_phones(x)[1] is None  # trained without CTC: no head


def test_animate_audio_shuts_the_lips_on_the_bilabials_the_head_hears(encdec, held_out, tmp_path):
    from vispeech.evaluation.closures import model_closed
    from vispeech.pipeline import animate_audio

    clip = clip_of(held_out[0])
    assert encdec.predict_with_closures(clip, 25)[1] is None  # closure_threshold 0: off
    hearing = load_model(encdec.save(tmp_path / "hearing")).set_params(closure_threshold=1e-3)  # an unsure head
    raw, heard = hearing.predict_with_closures(clip, 25)
    np.testing.assert_array_equal(raw.values, encdec.predict(clip, 25).values)
    bilabials = [p for p in heard if p.symbol != "sil"]
    assert bilabials and all(p.symbol in ("B", "M", "P") for p in bilabials)
    centres = [round(0.5 * (p.start + p.end) * 25) for p in bilabials]
    assert model_closed(animate_audio(clip, hearing, 25))[centres].all()
    assert not model_closed(animate_audio(clip, hearing, 25, postprocessing="none"))[centres].all()


@pytest.mark.parametrize("fixture,fps,memory", [("cnn", 25.0, 0), ("cnn", 30.0, 0), ("cnn", 50.0, 0), ("cnn", 60.0, 0),
                                                ("recurrent_cnn", 30.0, 0), ("cnn", 30.0, 0.3)])
def test_cnn_stream_equals_offline_prediction(fixture, fps, memory, request, held_out):
    cnn = copy.deepcopy(request.getfixturevalue(fixture))
    clip = clip_of(held_out[1])
    if memory:  # a normalisation of the last frames heard streams too
        remembering_all = cnn.predict(clip, fps).values
        cnn.encoding_ = replace(cnn.encoding_, memory_seconds=memory)
        assert not np.allclose(cnn.predict(clip, fps).values, remembering_all, atol=1e-3)
    offline = cnn.predict(clip, fps).values
    stream = cnn.stream("en", fps)
    rng = np.random.default_rng(int(fps))
    parts, i, expected_start = [], 0, 0
    while i < len(clip.samples):
        n = int(rng.integers(1, 1500))
        start, frames = stream.push(clip.samples[i:i + n])
        i += n
        assert start == expected_start
        expected_start += len(frames)
        # a frame is given only once the audio reaches its time plus the stream's delay
        assert expected_start <= max(0, np.ceil((i / RATE - stream.delay) * fps + 1e-9)) + 1
        parts.append(frames)
    parts.append(stream.finish()[1])
    np.testing.assert_allclose(np.concatenate(parts), offline, atol=1e-5)


def test_streams_advanced_together_give_what_each_gives_alone(cnn, recurrent_cnn, encdec, held_out, monkeypatch):
    """AudioStream.advance_together (what a server runs for the audio its sessions sent in one
    tick) gives every stream the frames it gets pushed alone, whatever the chunks, lengths and
    starts: the spectra of all the streams are one FFT, and the streams of one convolution
    network take each layer at once."""
    from vispeech.frontends import features
    from vispeech.models.networks import kernels
    from vispeech.models.networks.audio_stream import AudioStream

    gather, spectra = kernels._window_starts, features._windows_power
    products = []  # the layers run: each gathers its windows once
    ffts = []
    monkeypatch.setattr(kernels, "_window_starts", lambda *args: products.append(1) or gather(*args))
    monkeypatch.setattr(features, "_windows_power", lambda frames: ffts.append(len(frames)) or spectra(frames))
    sessions = [(cnn, 0, 0), (cnn, 1, 4), (recurrent_cnn, 2, 2), (cnn, 2, 9), (encdec, 0, 1), (recurrent_cnn, 1, 0)]
    rng = np.random.default_rng(3)
    plans = []  # each session's chunk sizes
    for _, u, _ in sessions:
        sizes = list(rng.integers(1, 1500, size=len(held_out[u].audio) // 100))
        plans.append(sizes[:int(np.searchsorted(np.cumsum(sizes), len(held_out[u].audio))) + 1])
    alone = []
    for (model, u, _), sizes in zip(sessions, plans):
        stream, audio, parts = model.stream(None, 30), held_out[u].audio, []
        for a, b in zip(np.cumsum([0, *sizes[:-1]]), np.cumsum(sizes)):
            parts.append(stream.push(audio[a:b])[1])
        alone.append(np.concatenate([*parts, stream.finish()[1]]))
    streams = [model.stream(None, 30) for model, _, _ in sessions]
    together = [[] for _ in sessions]
    for tick in range(max(start + len(sizes) for (_, _, start), sizes in zip(sessions, plans))):
        due = [k for k, ((_, _, start), sizes) in enumerate(zip(sessions, plans)) if start <= tick < start + len(sizes)]
        for k in due:
            _, u, start = sessions[k]
            a = sum(plans[k][: tick - start])
            streams[k].feed(held_out[u].audio[a:a + plans[k][tick - start]])
        products.clear()
        ffts.clear()
        AudioStream.advance_together([streams[k] for k in due])
        assert len(products) <= 6  # three layers for each convolution network, whatever the streams
        assert len(ffts) == 1  # every stream's new spectra at once
        for k in due:
            together[k].append(streams[k].collect()[1])
    for k, stream in enumerate(streams):
        frames = np.concatenate([*together[k], stream.finish()[1]])
        np.testing.assert_allclose(frames, alone[k], atol=1e-6)


def test_cnn_delay_is_its_look_ahead_plus_framing(cnn):
    assert cnn.lookahead == 8 and cnn.delay == pytest.approx(8 / 50 + 0.010 + 0.016)
    short = AudioCNNNetwork(look_ahead=3)
    assert [r for _, r in short._pads()] == [3, 0, 0]
    with pytest.raises(VispeechError, match="look_ahead"):
        AudioCNNNetwork(look_ahead=12)  # 7 + 3 + 1 frames is the most [15, 7, 3] can see ahead


def streamed_frames(model, clip: AudioClip, fps: float, chunk: int = 640) -> np.ndarray:
    """The frames ``model``'s stream gives for ``clip`` pushed ``chunk`` samples at a time."""
    stream = model.stream(None, fps)
    parts = [stream.push(clip.samples[i:i + chunk])[1] for i in range(0, len(clip.samples), chunk)]
    parts.append(stream.finish()[1])
    return np.concatenate(parts)


def test_encoder_decoder_stream_follows_its_offline_output(encdec, held_out):
    clip = clip_of(held_out[2])
    offline = encdec.predict(clip, 25).values
    streamed = streamed_frames(encdec, clip, 25)
    assert streamed.shape == offline.shape
    assert np.abs(streamed - offline).max() < 0.1
    assert np.corrcoef(streamed[:, 0], offline[:, 0])[0, 1] > 0.95


def test_match_level_gains_whole_clips_outside_the_training_levels_into_them(corpus, held_out, tmp_path):
    """match_level: fit stores the span of the training clips' levels; a clip within it is
    predicted bit for bit as without it, a quiet clip as one at the span's lower end whatever
    its level; training and streams are not gained; the span is saved."""
    from vispeech.frontends.features import power_spectrogram, speech_level

    model = AudioCNNNetwork(**{**TINY, "epochs": 3}, channels=[16, 16, 16], match_level=True)
    model.fit(corpus, progress=False)
    low, high = model.encoding_.level_range
    levels = [speech_level(power_spectrogram(u.audio), 24) for u in corpus.train]
    assert (low, high) == (min(levels), max(levels))
    unmatched = copy.deepcopy(model)
    unmatched.encoding_ = replace(unmatched.encoding_, level_range=[])
    plain = AudioCNNNetwork(**{**TINY, "epochs": 3}, channels=[16, 16, 16]).fit(corpus, progress=False)
    quiet_clip = AudioClip.from_array(held_out[0].audio * np.float32(0.01), RATE)
    np.testing.assert_array_equal(plain.predict(quiet_clip, 25).values, unmatched.predict(quiet_clip, 25).values)
    inside = next(u for u in held_out if low <= speech_level(power_spectrogram(u.audio), 24) <= high)
    np.testing.assert_array_equal(model.predict(clip_of(inside), 25).values,
                                  unmatched.predict(clip_of(inside), 25).values)

    def quiet(db: float) -> AudioClip:
        return AudioClip.from_array(inside.audio * np.float32(10 ** (db / 20)), RATE)

    quiet_power = power_spectrogram(quiet(-20).samples)
    assert speech_level(quiet_power, 24) < low - 10
    assert speech_level(model.encoding_.matched(quiet_power), 24) == pytest.approx(low, abs=1e-3)
    matched = model.predict(quiet(-20), 25).values
    np.testing.assert_allclose(model.predict(quiet(-10), 25).values, matched, atol=1e-4)
    assert not np.allclose(unmatched.predict(quiet(-20), 25).values, matched, atol=1e-3)
    stream = model.stream("en", 25)
    streamed = np.concatenate([stream.push(quiet(-20).samples)[1], stream.finish()[1]])
    np.testing.assert_allclose(streamed, unmatched.predict(quiet(-20), 25).values, atol=1e-5)
    assert load_model(model.save(tmp_path / "m")).encoding_.level_range == [low, high]
    with pytest.raises(VispeechError, match="match_level needs spectral features"):
        AudioCNNNetwork(features="encoder", encoder=str(tmp_path), fps=50, match_level=True)


@pytest.mark.parametrize("fixture", ["cnn", "recurrent_cnn", "encdec"])
def test_save_load_gives_identical_predictions(fixture, request, held_out, tmp_path):
    model = request.getfixturevalue(fixture)
    loaded = load_model(model.save(tmp_path / "model"))
    assert type(loaded) is type(model) and loaded.get_params() == model.get_params()
    assert loaded.phones_ == model.phones_ and loaded.phone_language_ == model.phone_language_ == "en"
    assert loaded.encoding_ == model.encoding_
    clip = clip_of(held_out[0])
    np.testing.assert_array_equal(loaded.predict(clip, 25).values, model.predict(clip, 25).values)


def test_ctc_head_learns_the_phone_labels(encdec, cnn):
    assert cnn.phones_ == ()  # no CTC: no head
    assert "sil" not in encdec.phones_ and {"AA", "M", "S"} <= set(encdec.phones_)
    assert encdec.weights_["ctc.weight"].shape[0] == len(encdec.phones_) + 1  # the blank


def test_augmentation_varies_the_inputs(corpus):
    model = create_model("audio-cnn", **{**TINY, "pitch_copies": 2, "epochs": 1}, channels=[8, 8, 8])
    model._prepare(list(corpus.train), corpus)
    example = model._encode_example(corpus.train[0], 10)
    assert len(example.powers) == 3  # the original and two pitch-shifted copies
    first, second = model._batches([(example, np.zeros((10, 2), np.float32))], np.random.default_rng(0)), \
        model._batches([(example, np.zeros((10, 2), np.float32))], np.random.default_rng(1))
    assert not np.allclose(first[0][0], second[0][0])
    fixed = model._batches([(example, np.zeros((10, 2), np.float32))], None)
    np.testing.assert_array_equal(fixed[0][0][0].numpy(), model.encoding_.encode(example.powers[0], 10))


def test_feature_dropout_silences_whole_dimensions_while_training(corpus):
    params = {**TINY, "pitch_copies": 0, "warp": 0.0, "feature_dropout": 0.5}
    model = create_model("audio-cnn", **params, channels=[8, 8, 8])
    model._prepare(list(corpus.train), corpus)
    example = model._encode_example(corpus.train[0], 10)
    full = model.encoding_.encode(example.powers[0], 10)
    (x, *_), = model._batches([(example, np.zeros((10, 2), np.float32))], np.random.default_rng(0))
    x = x[0].numpy().reshape(10, model.encoding_.stack, model.encoding_.dims)
    kept = (x != 0).any(axis=(0, 1))
    assert 0.2 < kept.mean() < 0.8  # about half the dimensions, the same in every frame and stacked slot
    np.testing.assert_array_equal(x[:, :, kept], full.reshape(x.shape)[:, :, kept])
    assert not x[:, :, ~kept].any()
    (fixed, *_), = model._batches([(example, np.zeros((10, 2), np.float32))], None)  # validation: untouched
    np.testing.assert_array_equal(fixed[0].numpy(), full)
    with pytest.raises(VispeechError, match="feature_dropout"):
        create_model("audio-cnn", feature_dropout=1.0)


def test_audio_networks_refuse_bad_input(cnn):
    with pytest.raises(VispeechError, match="animates audio"):
        cnn.predict(PhoneSequence([Phone("sil", 0.0, 1.0)], "en"), 25)
    with pytest.raises(VispeechError, match="not trained"):
        AudioCNNNetwork().predict(AudioClip.from_array(np.zeros(1600), RATE), 25)
    with pytest.raises(VispeechError, match="divide"):
        AudioCNNNetwork(fps=30.0)
    with pytest.raises(VispeechError, match="audio feature"):
        EncoderDecoderNetwork(features="spectrogram")
    with pytest.raises(VispeechError, match="GRU units"):
        AudioCNNNetwork(recurrent=-1)
    with pytest.raises(VispeechError, match="closure_length"):
        EncoderDecoderNetwork(closure_length=2.0)
    stream = cnn.stream(None, 25)
    with pytest.raises(VispeechError, match="non-finite"):
        stream.push(np.array([0.0, np.inf], dtype=np.float32))
    stream.finish()
    with pytest.raises(VispeechError, match="ended"):
        stream.push(np.zeros(10, dtype=np.float32))


def test_short_and_silent_audio(cnn):
    for n in (1, 100, 320, 321):
        clip = AudioClip.from_array(np.zeros(n, dtype=np.float32), RATE)
        track = cnn.predict(clip, 25)
        assert track.n_frames == clip.n_frames(25) and np.isfinite(track.values).all()
        stream = cnn.stream(None, 25)
        frames = [stream.push(clip.samples)[1], stream.finish()[1]]
        np.testing.assert_allclose(np.concatenate(frames), track.values, atol=1e-5)


def _new_speaker(utterances) -> list:
    """The utterances as a speaker whose jaw opens half as far from a lower rest would say them."""
    from dataclasses import replace

    return [replace(u, track=Track(0.15 + 0.5 * u.track.values, u.track.channels, u.track.fps)) for u in utterances]


def test_an_audio_network_adapts_to_a_new_speaker(cnn, corpus, held_out):
    """train --from for an audio network: warm-started on a few of a new speaker's utterances it
    predicts that speaker's held-out jaw better than before. How it compares with training from
    scratch on real speech: benchmarks/adapt_speaker.py --model grid-audio-cnn."""
    few = Splits(_new_speaker(corpus.train[:4]), _new_speaker(corpus.validation))
    target = _new_speaker(held_out)

    def error(model) -> float:
        return float(np.mean([np.mean((model.predict(clip_of(u), 25).select(["jawOpen"]).values[:, 0]
                                       - u.track["jawOpen"]) ** 2) for u in target]))

    adapted = copy.deepcopy(cnn).set_params(epochs=8, patience=8).fit(few, progress=False, warm_start=True)
    assert error(adapted) < 0.8 * error(cnn), (error(adapted), error(cnn))
    assert cnn.history_.epochs == 25  # the shipped model is untouched


def test_a_warm_start_refuses_phones_its_ctc_head_does_not_know(encdec, corpus):
    from dataclasses import replace

    swedish = [replace(u, phones=PhoneSequence([Phone("sj", 0.0, 0.5)], "sv")) for u in corpus.train[:2]]
    with pytest.raises(VispeechError, match="CTC head does not know: sj"):
        copy.deepcopy(encdec).set_params(epochs=1).fit(Splits(swedish), progress=False, warm_start=True)
