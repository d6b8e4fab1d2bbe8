"""The trainable networks on a tiny synthetic corpus whose targets are known functions of the phones."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from vispeech import Phone, PhoneSequence, Track, VispeechError
from vispeech.alignment.phones import n_frames_for
from vispeech.models.fitting import Splits
from vispeech.motion.arkit import THESIS_CHANNELS
from vispeech.models.networks.sliding_window import SlidingWindowNetwork, TaylorNetwork
from vispeech.models.networks.tdnn import LowLatencyNetwork, RecurrentStream, TimeDelayNetwork
from vispeech.models.registry import create_model, load_model
from vispeech.motion.arkit import ARKIT_NAMES
from vispeech.targets.presets import PRESETS

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
                                   "dropout": [0.1, 0.0], "epochs": 20, "learning_rate": 1e-2, **options})


def tiny_taylor(**options) -> TaylorNetwork:
    return TaylorNetwork(**{"hidden": [32, 32], "dropout": [0.1, 0.1], "epochs": 20, "batch_size": 16,
                            "learning_rate": 0.05, **options})


def tiny_tdnn(cls: type[TimeDelayNetwork] = TimeDelayNetwork, **options) -> TimeDelayNetwork:
    """A small ``tdnn-beskow`` network (windows of 4 frames each side) or, given another class, its windows."""
    windows = {"look_back": 4, "look_ahead": 4} if cls is TimeDelayNetwork else {}
    return cls(**{"hidden": 8, **windows, "fps": None, "epochs": 20, "batch_size": 3,
                  "learning_rate": 2e-2, **options})


@pytest.fixture(scope="module")
def thesis_model(corpus) -> SlidingWindowNetwork:
    return tiny_thesis().fit(corpus, progress=False)


@pytest.fixture(scope="module")
def tdnn_model(corpus) -> TimeDelayNetwork:
    return tiny_tdnn().fit(corpus, progress=False)


@pytest.fixture(scope="module")
def lowlatency_model(corpus) -> LowLatencyNetwork:
    return tiny_tdnn(LowLatencyNetwork, look_back=6, epochs=3).fit(corpus, progress=False)


def error_ratio(model, train, test) -> float:
    """jawOpen MSE of the model over that of the constant training-mean predictor, on ``test``."""
    mean = np.mean(np.concatenate([u.track["jawOpen"] for u in train]))
    model_error = [np.mean((model.predict(u.phones, FPS)["jawOpen"] - u.track["jawOpen"]) ** 2) for u in test]
    constant_error = [np.mean((mean - u.track["jawOpen"]) ** 2) for u in test]
    return float(np.mean(model_error) / np.mean(constant_error))


def test_thesis_network_learns_jaw_opening(thesis_model, corpus, held_out):
    assert thesis_model.is_fitted
    assert error_ratio(thesis_model, corpus, held_out) < 0.2
    assert thesis_model.history_.epochs >= thesis_model.history_.best_epoch > 0


def test_taylor_network_learns_jaw_opening(corpus, held_out):
    model = tiny_taylor().fit(corpus, progress=False)
    assert model.name == "sliding-window-taylor" and model.encoding_.linguistic
    assert error_ratio(model, corpus, held_out) < 0.3


def test_time_delay_network_learns_jaw_opening(tdnn_model, corpus, held_out):
    assert error_ratio(tdnn_model, corpus, held_out) < 0.2


def test_learned_state_is_numpy_and_hyper_parameters_stay(tdnn_model):
    assert tdnn_model.fps_ == FPS and tdnn_model.outputs_ == THESIS_CHANNELS
    assert all(isinstance(v, np.ndarray) for v in (*tdnn_model.weights_.values(), *tdnn_model.stats_.values()))
    params = tdnn_model.get_params()
    assert params["fps"] is None and params["look_ahead"] == 4 and "progress" not in params
    params["hidden"] = 99  # a copy
    assert tdnn_model.get_params()["hidden"] == 8


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
    assert {p.name for p in folder.iterdir()} == {"config.json", "weights.safetensors"}
    loaded = load_model(folder)
    assert type(loaded) is type(model) and loaded.name == model.name
    assert loaded.get_params() == model.get_params()
    assert loaded.history_ == model.history_
    assert loaded.postprocessing == model.postprocessing == "learned-jaw" and "learned-jaw" in PRESETS
    for utterance in held_out:
        a, b = model.predict(utterance.phones, FPS), loaded.predict(utterance.phones, FPS)
        assert a.channels == b.channels
        np.testing.assert_array_equal(a.values, b.values)
    # saved with fps 0 before it was refused (it trained at the corpus's rate, as null does): still loads
    config = json.loads((folder / "config.json").read_text())
    config["params"]["fps"] = 0
    (folder / "config.json").write_text(json.dumps(config))
    assert load_model(folder).get_params()["fps"] is None


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
    with pytest.raises(VispeechError, match="features"):
        thesis_model.stream("sv", FPS).push(swedish)


def push_one_by_one(stream, phones) -> tuple[list[int], np.ndarray]:
    """Push ``phones`` one at a time, then finish; the phones pushed when each frame came, and the frames."""
    pushed, chunks = [], []
    for count, phone in enumerate(phones, 1):
        start, rows = stream.push([phone])
        assert start == len(pushed)
        pushed += [count] * len(rows)
        chunks.append(rows)
    start, rows = stream.finish()
    assert start == len(pushed)
    pushed += [len(phones) + 1] * len(rows)  # after the end
    chunks.append(rows)
    return pushed, np.concatenate(chunks)


def test_streaming_equals_offline_and_waits_only_for_the_look_ahead(lowlatency_model, held_out):
    model = lowlatency_model
    assert model.name == "tdnn-lowlatency" and model.get_params()["look_ahead"] == 2
    assert model.get_params()["look_back"] == 6 and model.lookahead == 2
    phones = list(held_out[2].phones)
    stream = model.stream("en", FPS)
    assert isinstance(stream, RecurrentStream)
    assert (stream.fps, stream.lookahead) == (FPS, 2) and stream.channels == model.channels
    pushed, frames = push_one_by_one(stream, phones)
    for index, count in enumerate(pushed):
        if count <= len(phones):  # not yet the end of the stream
            assert phones[count - 1].end > (index + 2) / FPS  # inputs up to t + 2 known
    offline = model.predict(held_out[2].phones, FPS)
    assert len(frames) == offline.n_frames
    np.testing.assert_allclose(frames, offline.values, atol=1e-6)


def test_streaming_in_pieces_of_any_size_equals_offline(lowlatency_model, held_out):
    """Phones pushed in pieces of 1 to 11 (each piece's frames encoded at once) give what the
    whole sequence gives offline."""
    phones = list(held_out[1].phones)
    rng = np.random.default_rng(7)
    stream, chunks, i = lowlatency_model.stream("en", FPS), [], 0
    while i < len(phones):
        size = int(rng.integers(1, 12))
        chunks.append(stream.push(phones[i : i + size])[1])
        i += size
    chunks.append(stream.finish()[1])
    offline = lowlatency_model.predict(held_out[1].phones, FPS)
    np.testing.assert_allclose(np.concatenate(chunks), offline.values, atol=1e-6)


def test_streaming_emits_each_frame_as_soon_as_its_look_ahead_is_known(lowlatency_model):
    phones = [Phone("sil", 0.0, 0.2), Phone("M", 0.2, 0.3), Phone("AA", 0.3, 0.6)]
    pushed, frames = push_one_by_one(lowlatency_model.stream("en", FPS), phones)
    # sil covers frames 0-4: frames 0-2 need frames up to 4; M covers 5-7, so frames 3-5 come after it;
    # AA covers 8-14, so frames 6-12 come after it and the last two at the end.
    assert pushed == [1] * 3 + [2] * 3 + [3] * 7 + [4] * 2
    np.testing.assert_allclose(frames, lowlatency_model.predict(PhoneSequence(phones, "en"), FPS).values,
                               atol=1e-6)


@pytest.mark.parametrize(("fps", "lookahead"), [(50.0, 5), (30.0, 4), (12.5, 1), (60.0, 7), (29.97, 4)])
def test_streaming_at_another_frame_rate_equals_offline_resampled(lowlatency_model, held_out, fps, lookahead):
    """Frames at the stream's rate are interpolated from the model's as predict resamples them,
    each given by the time the phones cover ``lookahead`` frames after it."""
    model = lowlatency_model
    phones = list(held_out[2].phones)
    stream = model.stream("en", fps)
    assert (stream.fps, stream.lookahead) == (fps, lookahead)
    pushed, frames = push_one_by_one(stream, phones)
    np.testing.assert_allclose(frames, model.predict(held_out[2].phones, fps).values, atol=1e-6)
    for count, phone in enumerate(phones[:-1], 1):  # promised: every frame up to end - lookahead
        given = sum(1 for c in pushed if c <= count)
        assert given >= n_frames_for(phone.end, fps) - lookahead
    # and never one whose model frames need inputs not yet known
    for index, count in enumerate(pushed):
        if count <= len(phones):
            needed = int(np.ceil(index * FPS / fps - 1e-9)) + 2  # the later model frame, plus its look-ahead
            assert phones[count - 1].end > needed / FPS - 1e-6


def test_stream_refuses_out_of_order_phones_and_use_after_finish(lowlatency_model):
    stream = lowlatency_model.stream("en", FPS)
    stream.push([Phone("sil", 0.0, 0.2)])
    with pytest.raises(VispeechError, match="before the previous one ends"):
        stream.push([Phone("AA", 0.1, 0.3)])
    stream.finish()
    with pytest.raises(VispeechError, match="ended"):
        stream.push([Phone("AA", 0.2, 0.3)])


def test_resume_continues_epochs_exactly(corpus, held_out, tmp_path):
    straight = tiny_thesis(epochs=4, patience=None).fit(corpus, progress=False)
    first = tiny_thesis(epochs=2, patience=None).fit(corpus, progress=False, checkpoint_dir=tmp_path / "ckpt")
    assert first.history_.epochs == 2
    assert (tmp_path / "ckpt" / "training_state.json").is_file()
    resumed = tiny_thesis(epochs=4, patience=None).fit(corpus, progress=False, checkpoint_dir=tmp_path / "ckpt",
                                                       resume_from=tmp_path / "ckpt")
    assert resumed.history_.epochs == 4
    assert resumed.history_.train_loss == straight.history_.train_loss
    phones = held_out[0].phones
    np.testing.assert_array_equal(resumed.predict(phones, FPS).values, straight.predict(phones, FPS).values)
    assert load_model(tmp_path / "ckpt").history_.epochs == 4  # the checkpoint went on too


def test_checkpoint_folder_is_a_loadable_model(corpus, held_out, tmp_path):
    model = tiny_tdnn(epochs=2).fit(corpus, progress=False, checkpoint_dir=tmp_path / "ckpt")
    loaded = load_model(tmp_path / "ckpt")
    assert type(loaded) is TimeDelayNetwork and loaded.history_ == model.history_
    phones = held_out[0].phones
    np.testing.assert_array_equal(loaded.predict(phones, FPS).values, model.predict(phones, FPS).values)


def test_resume_refuses_other_parameters(thesis_model, corpus, tmp_path):
    thesis_model.save(tmp_path / "m")
    with pytest.raises(VispeechError, match="input_window"):
        tiny_thesis(input_window=7).fit(corpus, progress=False, resume_from=tmp_path / "m")


def test_fixed_seed_is_deterministic(corpus, held_out):
    phones = held_out[0].phones
    a = tiny_taylor(epochs=3).fit(corpus, progress=False).predict(phones, FPS).values
    b = tiny_taylor(epochs=3).fit(corpus, progress=False).predict(phones, FPS).values
    c = tiny_taylor(epochs=3, seed=1).fit(corpus, progress=False).predict(phones, FPS).values
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_validation_set_drives_early_stopping(corpus, held_out):
    model = tiny_tdnn(epochs=40, patience=2, learning_rate=0.2).fit(Splits(corpus, held_out), progress=False)
    history = model.history_
    assert all(v is not None for v in history.validation_loss)
    best = history.best_epoch
    assert history.validation_loss[best - 1] == min(history.validation_loss)
    assert history.epochs == 40 or history.epochs == best + 2


def test_a_plain_list_trains_without_validation(corpus):
    history = tiny_tdnn(epochs=2).fit(corpus, progress=False).history_
    assert history.validation_loss == [None, None]


@pytest.mark.parametrize("name", ["sliding-window-taylor", "sliding-window-thesis", "tdnn-beskow", "tdnn-lowlatency"])
def test_registry_creates_untrained_networks(name):
    model = create_model(name)
    assert model.name == model.family == name and not model.is_fitted
    with pytest.raises(VispeechError, match="is not trained"):
        model.predict(PhoneSequence([Phone("AA", 0.0, 0.3)], "en"), FPS)
    with pytest.raises(VispeechError, match="is not trained"):
        model.stream("en", FPS)
    with pytest.raises(VispeechError, match="must be trained first"):
        load_model(name)


def test_lowlatency_family_looks_28_back_and_2_ahead():
    params = LowLatencyNetwork().get_params()
    assert (params["look_back"], params["look_ahead"]) == (28, 2)
    assert (TimeDelayNetwork().get_params()["look_back"], TimeDelayNetwork().lookahead) == (15, 15)


def test_bad_parameters_and_corpora_raise(corpus):
    with pytest.raises(VispeechError, match="even"):
        SlidingWindowNetwork(input_window=6, output_window=5)
    with pytest.raises(VispeechError, match="no parameter"):
        TimeDelayNetwork(wings=3)
    with pytest.raises(VispeechError, match="no parameter 'preset'"):
        TimeDelayNetwork(preset="fast")
    with pytest.raises(VispeechError, match="no parameter 'progress'"):
        TimeDelayNetwork(progress=False)
    with pytest.raises(VispeechError, match="look_ahead"):
        TimeDelayNetwork(look_ahead=-1)
    # refused when made, not deep in training (a traceback) or silently kept
    for bad, message in ((dict(fps="abc"), "fps must be null"), (dict(fps=0), "fps must be positive"),
                         (dict(fps=True), "fps must be null"), (dict(fps=500), "fps must be between 1 and 240"),
                         (dict(motion_weight=float("nan")), "motion_weight"), (dict(motion_weight=-1), "motion_weight"),
                         (dict(mirror="maybe"), "mirror must be true or false"), (dict(standardize=3), "standardize"),
                         (dict(lr_step_down="x"), "lr_step_down"), (dict(linguistic=1), "linguistic")):
        with pytest.raises(VispeechError, match=message):
            TimeDelayNetwork(**bad)
    # accepted before: torch's own error at fit, torch's init used silently, a window the networks
    # refuse grown into a tree, a smoothing that asked for terabytes at predict
    for family, bad, message in (
        ("sliding-window-thesis", dict(dropout=[1.5, 0.1]), "dropout rates must be at least 0 and below 1"),
        ("sliding-window-thesis", dict(init="nope"), "unknown init 'nope' \\(use default or he\\)"),
        ("sliding-window-dtree", dict(input_window=4, output_window=5), "windows must satisfy"),
        ("beskow-rules", dict(sigma=1e9), "sigma must be seconds from 0 to 1"),
    ):
        with pytest.raises(VispeechError, match=message):
            create_model(family, **bad)
    unaligned = [SimpleNamespace(id="x", phones=None, track=corpus[0].track)]
    with pytest.raises(VispeechError, match="align"):
        tiny_thesis().fit(unaligned, progress=False)
    with pytest.raises(VispeechError, match="empty"):
        tiny_thesis().fit([], progress=False)
    with pytest.raises(VispeechError, match="lack target channels"):
        tiny_thesis(targets=["jawOpen", "noSuchShape"]).fit(corpus, progress=False)
