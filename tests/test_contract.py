"""The estimator contract (vispeech.models.contract) held by every family and every runnable model.

Hyper-parameters only in ``__init__`` (unknown ones refused), ``get_params`` never changed by
``fit``, ``fit(corpus) -> self`` with learned state in ``_`` attributes, ``predict`` refused
before fitting, one saved-folder format whose save → load round trip reproduces ``predict``,
and one name per model.
"""

import json

import numpy as np
import pytest
from conftest import random_sentence, require_module

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.espeak import synthesize
from vispeech.models.contract import Estimator, clone
from vispeech.models.fitting import Splits
from vispeech.models.persistence import FORMAT, FORMAT_VERSION
from vispeech.models.streams import ModelStream
from vispeech.models.networks.network import Network
from vispeech.models.registry import (
    DATA_FREE, FAMILIES, PRETRAINED, RUNNABLE, create_model, family_class, load_folder, load_model, pretrained_path,
)
from vispeech.utterance import Utterance
from vispeech.targets.presets import PRESETS

TRAINABLE = tuple(f for f in FAMILIES if f not in DATA_FREE and family_class(f).trainable)
NETWORK_TOLERANCE = 1e-9
"""How far a network's prediction may move through save → load (float32 weights, NumPy kernels)."""
RULE_TOLERANCE = 1e-12
CONFIG_KEYS = {"format", "version", "name", "family", "input", "vispeech", "channels", "params", "state", "arrays",
               "postprocessing"}
FPS = 25.0
SYMBOLS = ("AA", "IY", "UW", "B", "M", "S", "L", "F")
TINY_NETWORKS = {
    "sliding-window-thesis": {"input_window": 5, "output_window": 3, "hidden": [6, 6], "dropout": [0.0, 0.0]},
    "sliding-window-taylor": {"input_window": 5, "output_window": 3, "hidden": [6], "dropout": [0.0],
                              "batch_size": 16},
    "tdnn-beskow": {"look_back": 3, "look_ahead": 3, "hidden": 4, "delays": 2, "fps": None, "batch_size": 2},
    "tdnn-lowlatency": {"look_back": 4, "look_ahead": 1, "hidden": 4, "delays": 2, "fps": None, "batch_size": 2},
    "lstm-taylor": {"dense": 6, "hidden": 5, "batch_size": 2, "dropout": 0.0},
}
"""Small hyper-parameters for a quick fit of each network family on :func:`tiny_corpus`."""


def sentence(seed: int, language: str = "en") -> PhoneSequence:
    """Silence, 4–7 phones of 60–200 ms, silence."""
    symbols = SYMBOLS if language == "en" else ("a", "i:", "u:", "b", "m", "s", "l", "f")
    return random_sentence(np.random.default_rng(seed), symbols, language)


def tiny_corpus(seeds=range(4)) -> list[Utterance]:
    """English utterances whose jawOpen and mouthPucker tracks are Öhman's authored predictions at 25 fps."""
    teacher = create_model("ohman")
    return [Utterance(id=f"u{seed}", phones=p, track=teacher.predict(p, FPS).select(("jawOpen", "mouthPucker")))
            for seed, p in ((seed, sentence(seed)) for seed in seeds)]


def tiny_fitted(family: str) -> Estimator:
    """A model of ``family`` fitted briefly on :func:`tiny_corpus` (networks need torch)."""
    if family in TINY_NETWORKS:
        require_module("torch", "torch (the train extra: pip install vispeech[train])")
        params = {**TINY_NETWORKS[family], "targets": ["jawOpen", "mouthPucker"], "epochs": 2}
        return create_model(family, **params).fit(tiny_corpus(), progress=False, num_threads=1)
    if family == "sliding-window-dtree":
        return create_model(family, min_leaf=2, targets=["jawOpen", "mouthPucker"]).fit(tiny_corpus(), progress=False)
    return create_model(family, max_iterations=2).fit(tiny_corpus(), progress=False)


PROBES = [sentence(50), sentence(51), sentence(52, "sv")]
"""Phone sequences to compare predictions on (two English, one Swedish)."""


def audio_probes() -> list[AudioClip]:
    """Audio to compare audio models' predictions on: espeak-ng speech (English, Swedish) and noise."""
    clips = [AudioClip.from_array(s.audio, s.sample_rate) for s in (
        synthesize("Bin blue at F two now.", "en"), synthesize("Mamma plockar blåbär.", "sv"))]
    noise = np.random.default_rng(7).normal(0, 0.05, 12345).astype(np.float32)
    return clips + [AudioClip.from_array(noise, 22050)]


def probes_for(model: Estimator) -> list[PhoneSequence] | list[AudioClip]:
    """The probes the model can read (audio for an audio model; a network on phone identities
    reads its own language only)."""
    if model.input_kind == "audio":
        return audio_probes()
    encoding = getattr(model, "encoding_", None)
    if encoding is None or encoding.kind != "phones":
        return PROBES
    return [p for p in PROBES if p.language == encoding.language]


def runnable(name: str) -> Estimator:
    """``load_model(name)``; skips while a shipped model is not in the package yet."""
    if name in PRETRAINED and not pretrained_path(name).is_dir():
        pytest.skip(f"shipped model {name} is not trained yet ({pretrained_path(name)} absent)")
    return load_model(name)


def tolerance(model: Estimator) -> float:
    return NETWORK_TOLERANCE if isinstance(model, Network) else RULE_TOLERANCE


def assert_same_predictions(a: Estimator, b: Estimator) -> None:
    for inputs in probes_for(a):
        for fps in (30.0, FPS):
            x, y = a.predict(inputs, fps), b.predict(inputs, fps)
            assert x.channels == y.channels and x.n_frames == y.n_frames == inputs.n_frames(fps)
            np.testing.assert_allclose(y.values, x.values, rtol=0, atol=tolerance(a))


# -- every family ------------------------------------------------------------------------

@pytest.mark.parametrize("family", list(FAMILIES))
def test_every_family_obeys_the_contract(family):
    cls = family_class(family)
    assert issubclass(cls, Estimator) and cls.family == family
    model = create_model(family)
    assert type(model) is cls and model.name == family
    assert model.input_kind in ("phones", "audio") and isinstance(model.lookahead, int) and model.lookahead >= 0
    assert model.get_params() == dict(cls.defaults)
    params = model.get_params()
    params[next(iter(params))] = "changed"  # a copy: the model keeps its own
    assert model.get_params() == dict(cls.defaults)
    assert cls(**model.get_params()).get_params() == model.get_params()
    assert model.data_free == (family in DATA_FREE) == model.is_fitted
    assert model.postprocessing in PRESETS
    with pytest.raises(VispeechError, match=f"model {family} has no parameter 'no_such_parameter'"):
        cls(no_such_parameter=1)
    with pytest.raises(TypeError):
        cls({"window": 3})  # hyper-parameters by keyword only
    assert model.set_params(**model.get_params()) is model and model.get_params() == dict(cls.defaults)
    with pytest.raises(VispeechError, match=f"model {family} has no parameter 'no_such_parameter'"):
        model.set_params(no_such_parameter=1)
    fresh = clone(model)
    assert type(fresh) is cls and fresh is not model and fresh.get_params() == model.get_params()
    if model.is_fitted:
        track = model.predict(PROBES[0], FPS)
        assert track.channels == model.channels and track.n_frames == PROBES[0].n_frames(FPS)
        assert isinstance(model.stream("en", FPS), ModelStream)


@pytest.mark.parametrize("family", TRAINABLE)
def test_an_untrained_network_refuses_to_predict_and_names_training(family, tmp_path):
    model = create_model(family)
    expected = "audio" if model.input_kind == "audio" else "authored"  # audio networks need no phones, fitted or not
    assert not model.is_fitted and model.postprocessing == expected
    with pytest.raises(VispeechError, match=f"model {family} is not trained: fit it on a corpus"):
        model.predict(PROBES[0], FPS)
    with pytest.raises(VispeechError, match="not trained"):
        model.stream("en", FPS)
    with pytest.raises(VispeechError, match=f"model {family} must be trained first"):
        load_model(family)
    folder = model.save(tmp_path / "untrained")  # an untrained model saves its hyper-parameters only
    config = json.loads((folder / "config.json").read_text())
    assert config["state"] is None and config["arrays"] == [] and config["channels"] is None
    assert not (folder / "weights.safetensors").exists()
    loaded = load_folder(folder)
    assert type(loaded) is type(model) and not loaded.is_fitted and loaded.get_params() == model.get_params()
    with pytest.raises(VispeechError, match="not trained"):
        loaded.predict(PROBES[0], FPS)


@pytest.mark.parametrize("family", ["baseline", "beskow-rules"])
def test_authored_rules_refuse_to_fit(family):
    with pytest.raises(VispeechError, match=f"model {family} is data-free"):
        create_model(family).fit(tiny_corpus())


@pytest.mark.parametrize("family", ["cohen-massaro", "ohman", "sliding-window-dtree", *TINY_NETWORKS])
def test_fit_learns_into_underscore_attributes_and_leaves_the_parameters(family, tmp_path):
    if family in TINY_NETWORKS:
        require_module("torch", "torch (the train extra: pip install vispeech[train])")
        model = create_model(family, **TINY_NETWORKS[family], targets=["jawOpen", "mouthPucker"], epochs=2)
    elif family == "sliding-window-dtree":
        model = create_model(family, min_leaf=2, targets=["jawOpen", "mouthPucker"])
    else:
        model = create_model(family, max_iterations=2)
    params = model.get_params()
    before = set(vars(model))
    assert model.fit(tiny_corpus(), progress=False) is model
    assert model.get_params() == params and model.is_fitted
    learned = {key for key in set(vars(model)) - before if not key.startswith("_")}
    assert learned and all(key.endswith("_") for key in learned), learned
    assert model.history_.epochs >= 1 and all(v is None for v in model.history_.validation_loss)
    assert model.postprocessing == "learned-jaw"
    for phones in probes_for(model):
        track = model.predict(phones, FPS)
        assert track.channels == model.channels and track.n_frames == phones.n_frames(FPS)
        assert np.isfinite(track.values).all()
    # refitting on a corpus with a validation split: same parameters, a validation loss
    corpus = tiny_corpus()
    model.fit(Splits(corpus[:3], corpus[3:]), progress=False)
    assert model.get_params() == params and None not in model.history_.validation_loss


def test_fit_refuses_what_is_not_a_corpus():
    for family in ("cohen-massaro", "ohman"):
        with pytest.raises(VispeechError, match="empty"):
            create_model(family).fit([], progress=False)
        with pytest.raises(VispeechError, match="needs a corpus"):
            create_model(family).fit(3, progress=False)
        with pytest.raises(VispeechError, match="align"):
            create_model(family).fit([Utterance(track=tiny_corpus()[0].track)], progress=False)


# -- every runnable model ----------------------------------------------------------------

@pytest.mark.parametrize("name", RUNNABLE)
def test_runnable_models_are_known_by_the_name_they_were_loaded_by(name):
    model = runnable(name)
    assert model.name == name and model.is_fitted
    assert model.family == (name if name in DATA_FREE else json.loads(
        (pretrained_path(name) / "config.json").read_text())["family"])
    if name in PRETRAINED:
        assert model.postprocessing == ("audio" if model.input_kind == "audio" else "learned-jaw")
    assert repr(model).startswith(f"<{type(model).__name__} {name!r}")


@pytest.mark.parametrize("name", RUNNABLE)
def test_save_load_round_trip_reproduces_predict(name, tmp_path):
    model = runnable(name)
    folder = model.save(tmp_path / "saved")
    config = json.loads((folder / "config.json").read_text())
    assert set(config) == CONFIG_KEYS
    assert (config["format"], config["version"], config["name"], config["family"]) == (
        FORMAT, FORMAT_VERSION, name, model.family)
    assert config["input"] == model.input_kind and config["channels"] == list(model.channels)
    assert config["params"] == model.get_params() and config["postprocessing"] == model.postprocessing
    assert (folder / "weights.safetensors").exists() == bool(config["arrays"]) == (config["state"] is not None)
    for loaded in (load_model(folder), load_folder(folder), type(model).load(folder)):
        assert type(loaded) is type(model) and loaded.name == name and loaded.family == model.family
        assert loaded.get_params() == model.get_params() and loaded.channels == model.channels
        assert loaded.lookahead == model.lookahead and loaded.postprocessing == model.postprocessing
        assert_same_predictions(model, loaded)
    if name in PRETRAINED:  # the shipped folder itself loads to the same model
        assert_same_predictions(model, load_folder(pretrained_path(name)))


def test_set_params_checks_values_and_keeps_what_was_learned():
    model = tiny_fitted("sliding-window-dtree")
    before = model.predict(PROBES[0], FPS).values
    with pytest.raises(VispeechError, match="min_leaf must be a whole number"):
        model.set_params(min_leaf=0, seed=5)
    assert model.get_params()["min_leaf"] == 2 and model.get_params()["seed"] == 0  # left as it was
    assert model.set_params(min_leaf=3) is model and model.get_params()["min_leaf"] == 3 and model.is_fitted
    np.testing.assert_array_equal(model.predict(PROBES[0], FPS).values, before)
    fresh = clone(model)
    assert not fresh.is_fitted and fresh.get_params() == model.get_params() and fresh.name == fresh.family


@pytest.mark.parametrize("family", list(FAMILIES))
def test_a_value_of_the_wrong_kind_is_refused_not_a_crash(family):
    """Whatever JSON `vispeech train --param KEY=VALUE` passes, a model takes it or refuses it
    with a one-line VispeechError; set_params then leaves the values as they were."""
    model = create_model(family)
    before = model.get_params()
    for key in before:
        for value in ("abc", None, [1], {"a": 1}, -1, 1e12, float("nan"), True):
            try:
                create_model(family, **{key: value})
            except VispeechError as error:
                assert "\n" not in str(error)
            try:
                model.set_params(**{key: value})
            except VispeechError:
                assert model.get_params() == before
            else:
                model.set_params(**{key: before[key]})


@pytest.mark.parametrize(
    ("family", "key", "value", "default"),
    [
        ("audio-cnn", "dropout", "abc", "0.1"),
        ("audio-encdec", "fps", "abc", "50.0"),
        ("audio-cnn", "channels", None, "[256, 256, 256]"),
        ("sliding-window-taylor", "hidden", 5, "[3000, 3000, 3000]"),
    ],
)
def test_a_value_of_the_wrong_kind_is_named_with_its_default(family, key, value, default):
    with pytest.raises(VispeechError) as caught:
        create_model(family, **{key: value})
    assert str(caught.value) == f"model {family}: {key} must be like {default}, got {value!r}"


@pytest.mark.parametrize(
    ("family", "key", "value"),
    [
        ("tdnn-beskow", "batch_size", 0),
        ("tdnn-beskow", "seed", -1),
        ("tdnn-lowlatency", "learning_rate", -1),
        ("tdnn-beskow", "hidden", 0),
        ("tdnn-beskow", "groups", 1),
        ("lstm-taylor", "bidirectional", 0),
        ("sliding-window-taylor", "momentum", -1),
        ("sliding-window-dtree", "targets", 0),
        ("sliding-window-dtree", "seed", 0.0),
        ("audio-cnn", "patience", []),
        ("audio-cnn", "fps", 0),
        ("audio-encdec", "prior_seconds", [1]),
        ("audio-cnn", "memory_seconds", -1),
        ("audio-encdec", "memory_seconds", 1e12),
        ("audio-cnn", "match_level", 1),
    ],
)
def test_training_values_torch_or_scikit_learn_would_crash_on_are_refused_at_once(family, key, value):
    """Values of the right kind but out of range were taken, then crashed the fit in torch,
    NumPy or scikit-learn (`vispeech train` printed their traceback); they are refused when set."""
    with pytest.raises(VispeechError, match=f"{key} must be"):
        create_model(family, **{key: value})


def test_set_params_on_a_rule_model_takes_effect():
    model = create_model("baseline")
    phones = PhoneSequence([Phone("sil", 0.0, 0.1), Phone("AA", 0.1, 0.4), Phone("sil", 0.4, 0.5)], "en")
    open_jaw = model.predict(phones, FPS).select(("jawOpen",)).values.max()
    with pytest.raises(VispeechError):
        model.set_params(lead_in=-1)
    assert model.predict(phones, FPS).select(("jawOpen",)).values.max() == open_jaw
    model.set_params(targets={"en": {"AA": {"jawOpen": 0.0}}})
    assert model.predict(phones, FPS).select(("jawOpen",)).values.max() < open_jaw


@pytest.mark.parametrize("family", ["cohen-massaro", "ohman", "sliding-window-dtree", *TINY_NETWORKS])
def test_save_load_round_trip_of_a_fitted_model(family, tmp_path):
    model = tiny_fitted(family)
    assert model.name == family
    with pytest.raises(AttributeError):
        model.name = "my-model"  # read-only: a model is named by saving it
    loaded = load_model(model.save(tmp_path / "m", name="my-model"))
    assert type(loaded) is type(model) and loaded.name == model.name == "my-model" and loaded.is_fitted
    assert loaded.get_params() == model.get_params() and loaded.history_ == model.history_
    assert loaded.postprocessing == model.postprocessing == "learned-jaw"
    assert_same_predictions(model, loaded)


def test_a_folder_listing_the_retired_run_settings_still_loads(tmp_path):
    """Before they became keywords of fit, checkpoint_dir, num_threads and warm_start were a
    network's hyper-parameters; a folder saved then lists them."""
    model = tiny_fitted("tdnn-lowlatency")
    folder = model.save(tmp_path / "m")
    config = json.loads((folder / "config.json").read_text())
    config["params"] |= {"checkpoint_dir": "/gone", "num_threads": 2, "warm_start": False}
    (folder / "config.json").write_text(json.dumps(config))
    loaded = load_model(folder)
    assert loaded.get_params() == model.get_params()
    assert_same_predictions(model, loaded)


@pytest.mark.parametrize("family", ["cohen-massaro", "ohman", "sliding-window-dtree"])
def test_a_family_fitted_in_one_go_refuses_a_checkpoint_or_a_warm_start(family, tmp_path):
    model = create_model(family)
    with pytest.raises(VispeechError, match=f"model {family} is fitted in one go: it takes no checkpoint_dir"):
        model.fit(tiny_corpus(), progress=False, checkpoint_dir=tmp_path / "c")
    with pytest.raises(VispeechError, match=f"model {family} is fitted in one go: it takes no warm_start"):
        model.fit(tiny_corpus(), progress=False, warm_start=True)
    with pytest.raises(VispeechError, match=f"model {family} is fitted in one go: it takes no resume_from"):
        model.fit(tiny_corpus(), progress=False, resume_from=tmp_path / "c")


@pytest.mark.parametrize("name", RUNNABLE)
def test_streams_give_every_frame_once_in_order(name):
    model = runnable(name)
    inputs = probes_for(model)[0]
    if model.family == "audio-ensemble":  # it animates whole recordings only, and says so
        with pytest.raises(VispeechError, match="does not stream"):
            model.stream(None, 30.0)
        return
    stream = model.stream(getattr(inputs, "language", None), 30.0)
    assert stream.channels == model.channels and stream.fps == 30.0 and stream.lookahead >= 0
    if model.input_kind == "audio":  # 20 ms chunks of 16 kHz audio
        samples = inputs.resampled(16000).samples
        chunks = [stream.push(samples[i:i + 320]) for i in range(0, len(samples), 320)] + [stream.finish()]
    else:
        chunks = [stream.push([p]) for p in inputs] + [stream.finish()]
    starts = [start for start, _ in chunks]
    rows = np.concatenate([frames for _, frames in chunks])
    lengths = np.cumsum([0] + [len(frames) for _, frames in chunks])
    assert starts == list(lengths[:-1])  # contiguous, none twice
    assert rows.shape == (inputs.n_frames(30.0), len(model.channels)) and np.isfinite(rows).all()
    with pytest.raises(VispeechError, match="ended"):
        stream.push([])


def test_a_version_1_folder_is_refused(tmp_path):
    folder = load_model("cohen-massaro").save(tmp_path / "m")
    config = json.loads((folder / "config.json").read_text())
    old = {"format": FORMAT, "version": 1, "model": "cohen-massaro", "params": config["params"]}
    (folder / "config.json").write_text(json.dumps(old))
    with pytest.raises(VispeechError, match="format version 1; this vispeech reads 2"):
        load_model(folder)


@pytest.mark.parametrize("name", ["baseline", "beskow-rules", "ohman", "grid-cohen-massaro", "grid-tdnn",
                                  "grid-audio-cnn"])
def test_every_way_to_predict_checks_its_inputs_and_frame_rate_first(name):
    """``pipeline.animate`` checked the limits, ``Estimator.predict`` did not: a frame rate of 1e9
    got the process killed for memory, a phone ending at 1e9 s asked for 224 GiB, ``fps="30"`` met
    the frame arithmetic as text, and the wrong kind of input crashed deep inside."""
    from vispeech.models.registry import load_model

    model = load_model(name)
    phones = PhoneSequence([Phone("sil", 0.0, 0.1), Phone("AH", 0.1, 0.5)], "en")
    clip = AudioClip.from_array(np.zeros(8000, np.float32), 16000)
    given, other = (clip, phones) if model.input_kind == "audio" else (phones, clip)
    kind = "an AudioClip" if model.input_kind == "audio" else "a PhoneSequence"
    for bad_fps in (1e9, 2000, float("nan"), 0, "30", True):
        with pytest.raises(VispeechError, match="^fps must be"):
            model.predict(given, bad_fps)
    with pytest.raises(VispeechError, match=f"^{name} animates .*\\({kind}\\), not {type(other).__name__}$"):
        model.predict(other, 30)
    if model.input_kind == "phones":
        with pytest.raises(VispeechError, match="the utterance lasts 1e\\+09 s; the limit is 600 s"):
            model.predict(PhoneSequence([Phone("sil", 0.0, 0.1), Phone("AH", 0.1, 1e9)], "en"), 30)
        with pytest.raises(VispeechError, match="before the previous phone ends"):
            model.predict_many([phones, PhoneSequence([Phone("AH", 0.5, 0.9), Phone("IY", 0.2, 0.4)], "en")], 30)
    with pytest.raises(VispeechError, match="^fps must be"):
        model.stream("en", 0)
    assert model.predict(given, 30).n_frames == given.n_frames(30)


@pytest.mark.parametrize("family", list(FAMILIES))
def test_scikit_learns_clone_and_get_params_deep_work(family):
    """The contract says "an estimator in scikit-learn's sense", but ``sklearn.base.clone`` failed
    on every family: ``get_params`` took no ``deep``."""
    base = require_module("sklearn.base", "scikit-learn (the train extra)")
    model = create_model(family)
    assert model.get_params(deep=True) == model.get_params(deep=False) == model.get_params()
    copied = base.clone(model)
    assert type(copied) is type(model) and copied is not model and copied.get_params() == model.get_params()


@pytest.mark.parametrize("name", ["baseline", "beskow-rules", "ohman", "grid-cohen-massaro", "grid-tdnn"])
def test_a_stream_takes_phones_that_name_their_words_and_refuses_bad_ones(name):
    """The phones ``utter``, ``align`` and every reader give carry word indices; a window stream (the
    rules') refused them ("phone 1 (HH) refers to missing word 0") and took a phone at NaN seconds."""
    from vispeech.pipeline import utter

    phones = utter("Hello world, how are you?").phones
    assert any(p.word is not None for p in phones)
    model = load_model(name)
    stream = model.stream("en", 30.0)
    chunks = [stream.push(phones.phones[k : k + 3]) for k in range(0, len(phones), 3)] + [stream.finish()]
    rows = np.concatenate([frames for _, frames in chunks])
    assert rows.shape == (phones.n_frames(30.0), len(model.channels))
    jaw = model.channels.index("jawOpen")  # a window's view of the whole (the recurrent stream's is exact)
    assert np.corrcoef(rows[:, jaw], model.predict(phones, 30.0).values[:, jaw])[0, 1] > 0.8
    for bad, match in (([Phone("AH", float("nan"), 0.2)], "has start nan"),
                       ([Phone("AH", 0.0, 0.3), Phone("IY", 0.1, 0.4)], "before the previous")):
        with pytest.raises(VispeechError, match=match):
            model.stream("en", 30.0).push(bad)


def test_a_folder_is_loaded_from_a_string_and_a_path_names_only_folders(tmp_path):
    """``load_folder("/tmp/m")`` failed on a string (``str / str``), and ``load_model(Path("grid-tdnn"))``
    said "unknown model 'grid-tdnn': not one of grid-tdnn, ..."."""
    from pathlib import Path

    folder = load_model("ohman").save(tmp_path / "m")
    assert load_folder(str(folder)).family == load_model(str(folder)).family == "ohman"
    with pytest.raises(VispeechError, match=f"^no saved model folder at {tmp_path / 'none'}$"):
        load_model(tmp_path / "none")
    with pytest.raises(VispeechError, match="^no saved model folder at grid-tdnn$"):
        load_model(Path("grid-tdnn"))
