"""The trainable networks on a tiny synthetic corpus whose targets are known functions of the phones."""

from types import SimpleNamespace

import numpy as np
import pytest

from vispeech import Phone, PhoneSequence, Track, VispeechError
from vispeech.models.networks.network import THESIS_CHANNELS
from vispeech.models.registry import create_model, load_model
from vispeech.models.networks.sliding_window import SlidingWindowNetwork
from vispeech.models.networks.tdnn import TimeDelayNetwork
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.postprocess import LEARNED_JAW

VOWELS = ("AA", "AE", "IY", "UW", "OW", "EH")
CONSONANTS = ("P", "B", "M", "T", "S", "K", "F", "L")
CHANNELS = tuple(c for c in ARKIT_NAMES if c != "tongueOut")
FPS = 25.0


def synthetic_utterance(rng: np.random.Generator, index: int) -> SimpleNamespace:
    """CVCV... between silences; jawOpen 0.5 on vowels (smoothed), mouthSmileLeft 0.3 on IY/EH."""
    phones, t = [Phone("sil", 0.0, 0.2)], 0.2
    for k in range(int(rng.integers(6, 12))):
        pool = CONSONANTS if k % 2 == 0 else VOWELS
        duration = float(rng.uniform(0.06, 0.2))
        phones.append(Phone(pool[int(rng.integers(len(pool)))], t, t + duration))
        t += duration
    phones.append(Phone("sil", t, t + 0.2))
    sequence = PhoneSequence(phones, "en")
    labels = sequence.frame_labels(FPS)
    jaw = np.array([0.5 if label in VOWELS else 0.0 for label in labels])
    jaw = np.convolve(np.pad(jaw, 1, mode="edge"), [0.25, 0.5, 0.25], mode="valid")
    values = np.zeros((len(labels), len(CHANNELS)))
    values[:, CHANNELS.index("jawOpen")] = jaw
    values[:, CHANNELS.index("mouthSmileLeft")] = [0.3 if label in ("IY", "EH") else 0.0 for label in labels]
    return SimpleNamespace(id=f"utt{index}", phones=sequence, track=Track(values, CHANNELS, FPS))


@pytest.fixture(scope="module")
def corpus() -> list:
    rng = np.random.default_rng(0)
    return [synthetic_utterance(rng, i) for i in range(6)]


@pytest.fixture(scope="module")
def held_out() -> list:
    rng = np.random.default_rng(1)
    return [synthetic_utterance(rng, 100 + i) for i in range(3)]


def tiny_thesis(**options) -> SlidingWindowNetwork:
    return SlidingWindowNetwork(**{"input_window": 5, "output_window": 5, "hidden": [16, 16],
                                   "dropout": [0.1, 0.0], "epochs": 20, "learning_rate": 1e-2,
                                   "progress": False, "num_threads": 1, **options})


def tiny_taylor(**options) -> SlidingWindowNetwork:
    return SlidingWindowNetwork(**{"preset": "taylor", "hidden": [32, 32], "dropout": [0.1, 0.1],
                                   "epochs": 20, "batch_size": 16, "learning_rate": 0.05,
                                   "progress": False, "num_threads": 1, **options})


def tiny_tdnn(**options) -> TimeDelayNetwork:
    """A small ``beskow`` network (windows of 4 frames each side) or, given a preset, that preset's windows."""
    windows = {} if "preset" in options else {"look_back": 4, "look_ahead": 4}
    return TimeDelayNetwork(**{"hidden": 8, **windows, "fps": None, "epochs": 20, "batch_size": 3,
                               "learning_rate": 2e-2, "progress": False, "num_threads": 1, **options})


@pytest.fixture(scope="module")
def thesis_model(corpus) -> SlidingWindowNetwork:
    return tiny_thesis().fit(corpus)


@pytest.fixture(scope="module")
def tdnn_model(corpus) -> TimeDelayNetwork:
    return tiny_tdnn().fit(corpus)


def error_ratio(model, train, test) -> float:
    """jawOpen MSE of the model over that of the constant training-mean predictor, on ``test``."""
    mean = np.mean(np.concatenate([u.track["jawOpen"] for u in train]))
    model_error = [np.mean((model.predict(u.phones, FPS)["jawOpen"] - u.track["jawOpen"]) ** 2) for u in test]
    constant_error = [np.mean((mean - u.track["jawOpen"]) ** 2) for u in test]
    return float(np.mean(model_error) / np.mean(constant_error))


def test_thesis_network_learns_jaw_opening(thesis_model, corpus, held_out):
    assert error_ratio(thesis_model, corpus, held_out) < 0.2
    assert thesis_model.history.epochs >= thesis_model.history.best_epoch > 0


def test_taylor_network_learns_jaw_opening(corpus, held_out):
    model = tiny_taylor().fit(corpus)
    assert model.encoding.linguistic
    assert error_ratio(model, corpus, held_out) < 0.3


def test_time_delay_network_learns_jaw_opening(tdnn_model, corpus, held_out):
    assert error_ratio(tdnn_model, corpus, held_out) < 0.2


def test_outputs_mirror_left_channels_and_stay_in_unit_range(thesis_model, held_out):
    track = thesis_model.predict(held_out[0].phones, FPS)
    assert track.channels[:18] == THESIS_CHANNELS
    assert len(track.channels) == 26
    np.testing.assert_array_equal(track["mouthSmileRight"], track["mouthSmileLeft"])
    assert track.values.min() >= 0.0 and track.values.max() <= 1.0


def test_predict_covers_the_phones_at_any_fps(thesis_model, held_out):
    phones = held_out[1].phones
    for fps in (25.0, 30.0, 60.0):
        track = thesis_model.predict(phones, fps)
        assert track.fps == fps and track.n_frames == phones.n_frames(fps)
    at_25, at_50 = thesis_model.predict(phones, 25.0), thesis_model.predict(phones, 50.0)
    np.testing.assert_allclose(at_50.values[::2][: at_25.n_frames], at_25.values[: len(at_50.values[::2])], atol=1e-12)


@pytest.mark.parametrize("fixture", ["thesis_model", "tdnn_model"])
def test_save_load_gives_identical_predictions(fixture, request, held_out, tmp_path):
    model = request.getfixturevalue(fixture)
    folder = model.save(tmp_path / "model")
    assert {p.name for p in folder.iterdir()} == {"config.json", "weights.safetensors", "loss_curve.png"}
    assert (folder / "loss_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    loaded = load_model(folder)
    assert type(loaded) is type(model) and loaded.name == model.name
    assert loaded.history == model.history
    assert loaded.postprocessing == dict(LEARNED_JAW)  # a learned jaw is left to the model
    for utterance in held_out:
        a, b = model.predict(utterance.phones, FPS), loaded.predict(utterance.phones, FPS)
        assert a.channels == b.channels
        np.testing.assert_array_equal(a.values, b.values)


def test_feature_model_trained_on_english_drives_swedish(tdnn_model):
    swedish = PhoneSequence(
        [Phone("sil", 0.0, 0.1), Phone("m", 0.1, 0.18), Phone("A:", 0.18, 0.4, stress=1),
         Phone("rt", 0.4, 0.48), Phone("sil", 0.48, 0.7)], "sv")
    track = tdnn_model.predict(swedish, 30.0)
    assert track.n_frames == swedish.n_frames(30.0) == 21
    jaw = track["jawOpen"]
    assert jaw[int(0.3 * 30)] > jaw[int(0.14 * 30)] + 0.1  # open on A:, not on m


def test_phone_model_refuses_swedish(thesis_model):
    swedish = PhoneSequence([Phone("A:", 0.0, 0.2)], "sv")
    with pytest.raises(VispeechError, match="features"):
        thesis_model.predict(swedish, FPS)


def test_streaming_equals_offline_and_waits_only_for_the_look_ahead(corpus, held_out):
    model = tiny_tdnn(preset="beskow-lowlatency", look_back=6, epochs=3).fit(corpus)
    assert model.name == "tdnn-lowlatency" and model.params["look_ahead"] == 2
    phones = held_out[2].phones
    arrived = []

    def events():
        for phone in phones:
            arrived.append(phone)
            yield phone

    frames = []
    for index, values in model.predict_stream(events(), "en"):
        frames.append(values)
        if len(arrived) < len(phones):  # not yet the end of the stream
            assert arrived[-1].end > (index + 2) / FPS  # inputs up to t + 2 known
    offline = model.predict(phones, FPS)
    assert len(frames) == offline.n_frames
    np.testing.assert_allclose(np.array(frames), offline.values, atol=1e-9)


def test_streaming_emits_each_frame_as_soon_as_its_look_ahead_is_known(corpus):
    model = tiny_tdnn(preset="beskow-lowlatency", look_back=6, epochs=1).fit(corpus)
    phones = [Phone("sil", 0.0, 0.2), Phone("M", 0.2, 0.3), Phone("AA", 0.3, 0.6)]
    emitted_after = {}
    consumed = 0

    def events():
        nonlocal consumed
        for phone in phones:
            consumed += 1
            yield phone

    for index, _ in model.predict_stream(events()):
        emitted_after[index] = consumed
    # sil covers frames 0-4: frames 0-2 need frames up to 4; M covers 5-7, so frames 3-5 come after it.
    assert [emitted_after[k] for k in range(15)] == [1] * 3 + [2] * 3 + [3] * 9


def test_resume_continues_epochs_exactly(corpus, held_out, tmp_path):
    straight = tiny_thesis(epochs=4, patience=None).fit(corpus)
    first = tiny_thesis(epochs=2, patience=None).fit(corpus, checkpoint_dir=tmp_path / "ckpt")
    assert first.history.epochs == 2
    assert (tmp_path / "ckpt" / "training_state.json").is_file()
    resumed = tiny_thesis(epochs=4, patience=None).fit(corpus, resume_from=tmp_path / "ckpt")
    assert resumed.history.epochs == 4
    assert resumed.history.train_loss == straight.history.train_loss
    phones = held_out[0].phones
    np.testing.assert_array_equal(resumed.predict(phones, FPS).values, straight.predict(phones, FPS).values)


def test_checkpoint_folder_is_a_loadable_model(corpus, held_out, tmp_path):
    model = tiny_tdnn(epochs=2).fit(corpus, checkpoint_dir=tmp_path / "ckpt")
    loaded = load_model(tmp_path / "ckpt")
    phones = held_out[0].phones
    np.testing.assert_array_equal(loaded.predict(phones, FPS).values, model.predict(phones, FPS).values)


def test_resume_refuses_other_parameters(thesis_model, corpus, tmp_path):
    thesis_model.save(tmp_path / "m")
    with pytest.raises(VispeechError, match="input_window"):
        tiny_thesis(input_window=7).fit(corpus, resume_from=tmp_path / "m")


def test_fixed_seed_is_deterministic(corpus, held_out):
    phones = held_out[0].phones
    a = tiny_taylor(epochs=3).fit(corpus).predict(phones, FPS).values
    b = tiny_taylor(epochs=3).fit(corpus).predict(phones, FPS).values
    c = tiny_taylor(epochs=3, seed=1).fit(corpus).predict(phones, FPS).values
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_validation_set_drives_early_stopping(corpus, held_out):
    model = tiny_tdnn(epochs=40, patience=2, learning_rate=0.2).fit(corpus, validation=held_out)
    history = model.history
    assert all(v is not None for v in history.validation_loss)
    best = history.best_epoch
    assert history.validation_loss[best - 1] == min(history.validation_loss)
    assert history.epochs == 40 or history.epochs == best + 2


@pytest.mark.parametrize("name", ["sliding-window-taylor", "sliding-window-thesis", "tdnn-beskow", "tdnn-lowlatency"])
def test_registry_creates_untrained_networks(name):
    model = create_model(name)
    assert model.name == name
    with pytest.raises(VispeechError, match="model is not trained|is not trained"):
        model.predict(PhoneSequence([Phone("AA", 0.0, 0.3)], "en"), FPS)


def test_bad_parameters_and_corpora_raise(corpus):
    with pytest.raises(VispeechError, match="even"):
        SlidingWindowNetwork(input_window=6, output_window=5)
    with pytest.raises(VispeechError, match="no parameter"):
        TimeDelayNetwork(wings=3)
    with pytest.raises(VispeechError, match="preset"):
        TimeDelayNetwork(preset="fast")
    unaligned = [SimpleNamespace(id="x", phones=None, track=corpus[0].track)]
    with pytest.raises(VispeechError, match="align"):
        tiny_thesis().fit(unaligned)
    with pytest.raises(VispeechError, match="lack target channels"):
        tiny_thesis(targets=["jawOpen", "noSuchShape"]).fit(corpus)
