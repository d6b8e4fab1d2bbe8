"""The data-free control models: shapes, closures after post-processing, save/load, maths."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d
from scipy.signal import find_peaks

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.contract import Estimator
from vispeech.models.rules.baseline import Baseline
from vispeech.models.rules.beskow_rules import gaussian_smooth
from vispeech.models.rules.cohen_massaro import CohenMassaro
from vispeech.models.rules.ohman import Ohman
from vispeech.models.registry import create_model, load_folder, load_model
from vispeech.motion.easing import smoothstep
from vispeech.targets.tables import TARGET_CHANNELS, target_matrix
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.phonetics.inventory import get_inventory, is_silence, is_vowel
from vispeech.postprocess import postprocess
from vispeech.motion.easing import bezier_ease

DATA_FREE = ("baseline", "beskow-rules", "cohen-massaro", "ohman")
BILABIALS = {"sv": {"p", "b", "m"}, "en": {"P", "B", "M"}}
LABIODENTALS = {"sv": {"f", "v"}, "en": {"F", "V"}}


def random_sentence(seed: int, language: str, seconds: float = 3.0) -> PhoneSequence:
    """Silence, random consonant clusters and vowels of 25–160 ms, a pause, silence."""
    rng = np.random.default_rng(seed)
    inventory = get_inventory(language)
    vowels = sorted(inventory.vowels)
    consonants = [s for s in inventory.symbols if s not in inventory.vowels and not is_silence(s)]
    phones, t = [Phone("sil", 0.0, 0.3)], 0.3
    while t < seconds - 0.3:
        if rng.random() < 0.05:
            phones.append(Phone("sp", t, t + 0.12))
            t += 0.12
        for symbol in [*rng.choice(consonants, rng.integers(0, 4)), rng.choice(vowels)]:
            duration = float(rng.uniform(0.025, 0.16))
            phones.append(Phone(str(symbol), t, t + duration, stress=int(rng.integers(0, 3))))
            t += duration
    phones.append(Phone("sil", t, t + 0.25))
    return PhoneSequence(phones, language)


def hand_sentence(language: str) -> PhoneSequence:
    """Starts on a consonant at a gap, has a bilabial shorter than a frame and ends without silence."""
    a, m, p, f, i, k = ("a", "m", "p", "f", "i:", "k") if language == "sv" else ("AA", "M", "P", "F", "IY", "K")
    phones = [
        Phone(m, 0.05, 0.12), Phone(a, 0.12, 0.30, stress=1), Phone(p, 0.30, 0.315), Phone(i, 0.315, 0.45),
        Phone(f, 0.50, 0.58), Phone(a, 0.58, 0.70), Phone(k, 0.70, 0.76), Phone(m, 0.76, 0.84), Phone(i, 0.84, 0.99),
    ]
    return PhoneSequence(phones, language)


SENTENCES = [(lang, hand_sentence(lang)) for lang in ("sv", "en")] + [
    (lang, random_sentence(seed, lang)) for seed in range(4) for lang in ("sv", "en")
]


def frames_of(phone: Phone, fps: float, n_frames: int) -> np.ndarray:
    """Frames inside a phone, or the nearest frame to its centre if it is shorter than a frame."""
    first = int(np.ceil(phone.start * fps - 1e-9))
    last = int(np.ceil(phone.end * fps - 1e-9)) - 1
    if last < first:
        first = last = round((phone.start + phone.end) / 2 * fps)
    return np.arange(max(first, 0), min(last, n_frames - 1) + 1)


@pytest.fixture(scope="module", params=DATA_FREE)
def model(request):
    return create_model(request.param)


@pytest.mark.parametrize("fps", [30.0, 60.0, 25.0])
def test_track_covers_the_alignment_in_range(model, fps):
    for _, phones in SENTENCES:
        track = model.predict(phones, fps)
        assert track.n_frames == phones.n_frames(fps)
        assert track.channels == TARGET_CHANNELS == model.channels
        assert track.start_time == 0 and track.fps == fps
        assert track.values.min() >= 0.0 and track.values.max() <= 1.0


def test_postprocessed_bilabials_close_and_labiodentals_touch(model):
    fps = 30.0
    closures = contacts = 0
    for lang, phones in SENTENCES:
        track = postprocess(model.predict(phones, fps), phones)
        aperture = lip_aperture(track)
        for phone in phones:
            frames = frames_of(phone, fps, track.n_frames)
            if phone.symbol in BILABIALS[lang]:
                assert aperture[frames].min() <= LIP_CLOSED, (lang, phone, aperture[frames])
                closures += 1
            if phone.symbol in LABIODENTALS[lang]:
                touching = (aperture[frames] <= LIP_CLOSED) & (track["mouthRollLower"][frames] >= 0.3)
                assert touching.any(), (lang, phone)
                contacts += 1
    assert closures >= 15 and contacts >= 5


def test_postprocessed_jaw_peaks_fall_inside_vowels(model):
    fps = 30.0
    for lang, phones in SENTENCES:
        jaw = postprocess(model.predict(phones, fps), phones)["jawOpen"]
        peaks, _ = find_peaks(jaw, prominence=0.02, height=0.05)
        assert len(peaks) > 0
        vowels = [p for p in phones if is_vowel(p.symbol, lang)]
        for k in peaks:
            t = k / fps
            assert any(v.start - 1 / fps <= t <= v.end + 1 / fps for v in vowels), (lang, model.name, t)


def test_save_load_round_trip_predicts_identically(model, tmp_path):
    params = model.get_params()
    params["targets"] = {"sv": {"a": {"jawOpen": 0.5}}, "en": {"AA": {"mouthFunnel": None}}}
    original = type(model)(**params)
    folder = original.save(tmp_path / "saved")
    config = json.loads((folder / "config.json").read_text())
    assert config["name"] == config["family"] == model.family and config["params"] == params
    assert config["format"] == "vispeech-model" and config["version"] == 2 and config["state"] is None
    assert config["postprocessing"] == "authored" and config["channels"] == list(TARGET_CHANNELS)
    assert not (folder / "weights.safetensors").exists()  # authored parameters only: no arrays
    for loaded in (load_model(folder), load_folder(folder), type(model).load(folder)):
        assert type(loaded) is type(model) and loaded.get_params() == params and loaded.name == model.family
        for _, phones in SENTENCES[:4]:
            assert np.array_equal(loaded.predict(phones, 30).values, original.predict(phones, 30).values)


def test_unknown_model_and_parameter_are_refused():
    with pytest.raises(VispeechError, match="baseline"):
        create_model("no-such-model")
    with pytest.raises(VispeechError, match="cohen-massaro"):
        load_model("no-such-model")
    with pytest.raises(VispeechError, match="no parameter"):
        create_model("ohman", smoothing=3)
    with pytest.raises(VispeechError, match="data-free"):
        create_model("baseline").fit(None)
    with pytest.raises(VispeechError, match="data-free"):
        create_model("beskow-rules").fit([])


@pytest.mark.parametrize(
    "params",
    [{"window": 0}, {"alpha": {"default": -1.0}}, {"c": {"vowel": 2.0}}, {"theta": {"default": 1.0, "xyz": 2.0}}],
)
def test_bad_cohen_massaro_params_are_refused(params):
    with pytest.raises(VispeechError):
        CohenMassaro(**params)


def test_bad_params_of_other_models_are_refused():
    with pytest.raises(VispeechError):
        Ohman(w_c={"default": 1.5})
    with pytest.raises(VispeechError):
        Baseline(lead_in=-1)
    with pytest.raises(VispeechError):
        create_model("beskow-rules", hold=2.0)
    with pytest.raises(VispeechError):
        create_model("baseline", targets={"sv": {"a": {"jawOpen": 7}}})


def _fitted_ohman() -> Ohman:
    """An Öhman model fitted (one iteration) to the baseline's jawOpen on two sentences."""
    from vispeech.corpus import Utterance

    baseline = create_model("baseline")
    swedish = [phones for lang, phones in SENTENCES if lang == "sv"][:2]
    utterances = [Utterance(f"u{k}", "", Path("none.wav"), phones.duration,
                            baseline.predict(phones, 30).select(("jawOpen",)), phones=phones)
                  for k, phones in enumerate(swedish)]
    return Ohman(max_iterations=1).fit(utterances, progress=False)


def test_corrupt_or_missing_folders_are_refused(tmp_path):
    with pytest.raises(VispeechError):
        load_model(tmp_path / "missing")
    with pytest.raises(VispeechError, match="config.json"):
        load_folder(tmp_path)
    folder = create_model("ohman").save(tmp_path / "m")
    config = json.loads((folder / "config.json").read_text())
    with pytest.raises(VispeechError, match="not a baseline"):
        Baseline.load(folder)
    bad_configs = [
        "{not json",
        json.dumps({**config, "family": "nonexistent"}),
        json.dumps({key: value for key, value in config.items() if key != "params"}),
        json.dumps({key: value for key, value in config.items() if key != "family"}),
        json.dumps({**config, "format": "something-else"}),
        json.dumps({**config, "version": 99}),
        json.dumps({**config, "version": 1}),
        json.dumps({**config, "name": 3}),
        json.dumps({**config, "input": "video"}),
        json.dumps({**config, "postprocessing": {"jaw_shift": 0.0}}),
        json.dumps({**config, "params": {**config["params"], "w_c": {"default": 7}}}),
        json.dumps({**config, "params": {**config["params"], "smoothing": 3}}),
        json.dumps({**config, "state": [1]}),
        json.dumps({**config, "state": {"channels": ["jawOpen"]}}),
        json.dumps({**config, "channels": ["jawOpen"]}),
        json.dumps({**config, "arrays": 3}),
        json.dumps({**config, "params": {**config["params"], "targets": [1]}}),
    ]
    for text in bad_configs:
        (folder / "config.json").write_text(text)
        with pytest.raises(VispeechError):
            load_model(folder)
    # a fitted model's learned tables must be there, under the names and shapes its config lists
    fitted = _fitted_ohman().save(tmp_path / "fitted")
    config = json.loads((fitted / "config.json").read_text())
    weights = (fitted / "weights.safetensors").read_bytes()
    assert config["state"]["channels"] == ["jawOpen"] and config["arrays"] == ["sv.targets", "sv.w_c"]
    assert config["postprocessing"] == "learned-jaw"
    from safetensors.numpy import save as to_safetensors

    for text, data in [
        (json.dumps({**config, "arrays": ["sv.targets", "sv.w_c", "w"]}), weights),
        (json.dumps({**config, "arrays": ["sv.targets"]}), weights),
        (json.dumps(config), b"garbage"),
        (json.dumps(config), to_safetensors({"sv.targets": np.zeros((2, 2)), "sv.w_c": np.zeros((2, 2))})),
        (json.dumps(config), to_safetensors({"sv.targets": np.zeros((2, 2)), "sv.alpha": np.zeros((2, 2))})),
    ]:
        (fitted / "config.json").write_text(text)
        (fitted / "weights.safetensors").write_bytes(data)
        with pytest.raises(VispeechError):
            load_model(fitted)
    (fitted / "config.json").write_text(json.dumps(config))
    (fitted / "weights.safetensors").unlink()
    with pytest.raises(VispeechError, match="weights"):
        load_model(fitted)


class _ArrayModel(Estimator):
    """A model with arrays, to exercise weights.safetensors (not registered: loaded through its class)."""

    family = "test-arrays"
    defaults = {"gain": 1.0}
    channels = ("jawOpen",)

    def _fit(self, corpus, run):
        self.weights_ = np.arange(3.0) * self._params["gain"]
        return self

    def predict(self, phones, fps):
        raise NotImplementedError

    def _learned_state(self):
        if not hasattr(self, "weights_"):
            return None
        return {"size": len(self.weights_)}, {"weights": self.weights_}

    def _set_learned_state(self, state, arrays):
        if len(arrays["weights"]) != state["size"]:
            raise ValueError("wrong size")
        self.weights_ = arrays["weights"]


def test_arrays_round_trip_through_safetensors_without_pickle(tmp_path):
    from safetensors.numpy import save as to_safetensors

    model = _ArrayModel(gain=2.0)
    assert not model.is_fitted and model.postprocessing == "authored"
    unfitted = _ArrayModel.load(model.save(tmp_path / "u"))
    assert not unfitted.is_fitted and not (tmp_path / "u" / "weights.safetensors").exists()
    model.fit(None)
    model.weights_ = np.array([0.25, -1.5, 3.0])
    folder = model.save(tmp_path / "a")
    assert json.loads((folder / "config.json").read_text())["arrays"] == ["weights"]
    assert not any(path.suffix in (".npz", ".npy", ".pkl") for path in folder.iterdir())
    loaded = _ArrayModel.load(folder)
    assert loaded.is_fitted and loaded.postprocessing == "learned-jaw"
    assert loaded.get_params() == {"gain": 2.0} and np.array_equal(loaded.weights_, [0.25, -1.5, 3.0])
    assert loaded.weights_.dtype == np.float64
    (folder / "weights.safetensors").write_bytes(to_safetensors({"weights": np.zeros(4)}))
    with pytest.raises(VispeechError, match="corrupt model state"):
        _ArrayModel.load(folder)
    (folder / "weights.safetensors").write_bytes(to_safetensors({"other": np.zeros(3)}))
    with pytest.raises(VispeechError):
        _ArrayModel.load(folder)
    (folder / "weights.safetensors").write_bytes(b"garbage")
    with pytest.raises(VispeechError, match="cannot read model weights"):
        _ArrayModel.load(folder)


def test_cohen_massaro_matches_a_hand_computed_two_segment_value():
    phones = PhoneSequence([Phone("a", 0.0, 0.1), Phone("m", 0.1, 0.3)], "sv")
    params = {
        "alpha": {"default": 1.0, "sv:m": 2.0},
        "theta": {"default": 10.0, "sv:a": 8.0},
        "phi": {"default": 12.0, "sv:m": 6.0},
        "c": {"default": 1.5, "sv:m": 0.8},
    }
    targets, _ = target_matrix(["a", "m"], "sv")
    for window in (1, 6):
        track = CohenMassaro(**params, window=window).predict(phones, fps=10.0)
        for k, t in enumerate(track.times):
            d_a = 1.0 * np.exp(-(12.0 if t < 0.05 else 8.0) * abs(t - 0.05) ** 1.5)
            d_m = 2.0 * np.exp(-(6.0 if t < 0.2 else 10.0) * abs(t - 0.2) ** 0.8)
            expected = (d_a * targets[0] + d_m * targets[1]) / (d_a + d_m)
            np.testing.assert_allclose(track.values[k], np.clip(expected, 0, 1), rtol=1e-12, atol=1e-12)


def test_ohman_without_coarticulation_is_the_vowel_track():
    phones = PhoneSequence(
        [Phone("sil", 0, 0.2), Phone("k", 0.2, 0.3), Phone("a", 0.3, 0.5), Phone("t", 0.5, 0.6),
         Phone("s", 0.6, 0.7), Phone("u:", 0.7, 0.9), Phone("sil", 0.9, 1.2)],
        "sv",
    )
    targets, _ = target_matrix(phones.symbols, "sv")
    anchors = [0, 2, 5, 6]
    centres = np.array([(phones.phones[i].start + phones.phones[i].end) / 2 for i in anchors])
    times = np.arange(phones.n_frames(50)) / 50
    expected = np.empty((len(times), len(TARGET_CHANNELS)))
    for k, t in enumerate(times):
        m = int(np.clip(np.searchsorted(centres, t, side="right") - 1, 0, len(centres) - 2))
        s = np.clip((t - centres[m]) / (centres[m + 1] - centres[m]), 0, 1)
        expected[k] = targets[anchors[m]] + (3 * s**2 - 2 * s**3) * (targets[anchors[m + 1]] - targets[anchors[m]])
    track = Ohman(w_c={"default": 0.0}).predict(phones, 50)
    np.testing.assert_allclose(track.values, expected, atol=1e-12)
    # with full coarticulation a consonant reaches its own target at its centre (0.25 s = frame 25)
    full = Ohman(w_c={"default": 1.0}).predict(phones, 100)
    np.testing.assert_allclose(full.values[25], targets[1], atol=1e-12)


def test_smoothstep_endpoints():
    assert smoothstep(np.array([-1.0, 0.0, 0.5, 1.0, 2.0])).tolist() == [0.0, 0.0, 0.5, 1.0, 1.0]
    np.testing.assert_allclose(smoothstep(np.array([0.0025, 0.00425, 0.006, 0.01]), (0.0025, 0.006)), [0, 0.5, 1, 1])


def test_beskow_rules_interpolate_undefined_targets_linearly():
    phones = PhoneSequence([Phone("u:", 0.0, 0.2), Phone("t", 0.2, 0.3), Phone("s", 0.3, 0.4), Phone("i:", 0.4, 0.6)], "sv")
    values, defined = target_matrix(phones.symbols, "sv")
    pucker = TARGET_CHANNELS.index("mouthPucker")
    assert not defined[1, pucker] and not defined[2, pucker] and defined[0, pucker] and defined[3, pucker]
    track = create_model("beskow-rules", hold=0.0, sigma=0.0).predict(phones, 100)
    for frame in (25, 35):  # centres of /t/ and /s/
        expected = values[0, pucker] + (frame / 100 - 0.1) / 0.4 * (values[3, pucker] - values[0, pucker])
        assert track["mouthPucker"][frame] == pytest.approx(expected)
    jaw = TARGET_CHANNELS.index("jawOpen")
    assert track["jawOpen"][25] == pytest.approx(values[1, jaw])  # /t/ defines its jaw


@pytest.mark.parametrize(("frames", "sigma"), [(1, 2.0), (5, 3.7), (40, 0.1), (40, 1.2), (300, 7.5)])
def test_beskow_smoothing_gives_scipys_gaussian_filter(frames, sigma):
    """NumPy's smoothing, tracks shorter than the kernel included, is SciPy's (the core has no SciPy)."""
    values = np.random.default_rng(frames).random((frames, 4))
    np.testing.assert_allclose(gaussian_smooth(values, sigma),
                               gaussian_filter1d(values, sigma, axis=0, mode="nearest"), atol=1e-12, rtol=0)


def test_baseline_apices_lead_in_and_bezier_easing():
    phones = PhoneSequence([Phone("sil", 0, 0.5), Phone("a", 0.5, 0.8), Phone("t", 0.8, 0.9), Phone("sil", 0.9, 1.2)], "sv")
    values, _ = target_matrix(phones.symbols, "sv")
    sil, a = values[0], values[1]
    track = create_model("baseline").predict(phones, 30)
    np.testing.assert_allclose(track.values[:11], np.tile(sil, (11, 1)))  # silence held to 5 frames before /a/
    np.testing.assert_allclose(track.values[15], a)  # apex: first frame of the /a/ segment
    np.testing.assert_allclose(track.values[12], sil + bezier_ease(2, 5) * (a - sil))
    np.testing.assert_allclose(track.values[20], a + bezier_ease(5, 12) * (sil - a))  # /t/ belongs to /a/'s segment
    np.testing.assert_allclose(track.values[27:], np.tile(sil, (9, 1)))


def test_models_refuse_unknown_phones_and_languages():
    for name in DATA_FREE:
        with pytest.raises(VispeechError):
            create_model(name).predict(PhoneSequence([Phone("QQ", 0, 0.1)], "sv"), 30)
        with pytest.raises(VispeechError):
            create_model(name).predict(PhoneSequence([Phone("a", 0, 0.1)], "xx"), 30)
        with pytest.raises(VispeechError):
            create_model(name).predict(PhoneSequence([], "sv"), 30)
