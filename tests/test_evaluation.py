"""Objective metrics, lip closures and the evaluation report on tiny synthetic utterances."""

import math
from pathlib import Path

import numpy as np
import pytest

from vispeech import PhoneSequence, Track, VispeechError
from vispeech.alignment.phones import Phone, Word
from vispeech.corpus import Corpus, Utterance
from vispeech.corpus.articulation import lip_gap
from vispeech.evaluation import (
    ClosureCounts, count_closures, evaluate_models, model_channels, model_closed, mse, pearson_r, rmse_percent,
    score_channels, speech_frames, tracked_closed, value_range,
)
from vispeech.evaluation.closures import phone_frames
from vispeech.evaluation.plots import plot_utterance
from vispeech.evaluation.metrics import best_lag, motion_profile
from vispeech.evaluation.report import predict_on_frames, scored_frames
from vispeech.models.contract import Estimator
from vispeech.models.registry import create_model

FPS = 10.0


# -- metrics -------------------------------------------------------------------------------

def test_speech_frames_span_first_word_to_last_with_margin():
    words = [Word("a", 1.0, 1.4), Word("b", 1.5, 2.0)]
    mask = speech_frames(words, FPS, 30)
    assert np.flatnonzero(mask).tolist() == list(range(9, 22))  # 0.9 s .. 2.1 s inclusive
    shifted = speech_frames(words, FPS, 30, start_time=0.5)  # frame k at 0.5 + k/10
    assert np.flatnonzero(shifted).tolist() == list(range(4, 17))
    assert np.flatnonzero(speech_frames(words, FPS, 30, margin=0.0)).tolist() == list(range(10, 21))
    assert not speech_frames([], FPS, 30).any()


def test_metrics_match_numpy_references():
    rng = np.random.default_rng(0)
    target = rng.normal(size=(50, 3))
    predicted = 0.5 * target + rng.normal(scale=0.3, size=(50, 3))
    predicted[:, 2] = 0.7  # constant prediction: r undefined
    np.testing.assert_allclose(mse(target, predicted), ((target - predicted) ** 2).mean(axis=0))
    r = pearson_r(target, predicted)
    for j in range(2):
        assert r[j] == pytest.approx(np.corrcoef(target[:, j], predicted[:, j])[0, 1], abs=1e-12)
    assert np.isnan(r[2])
    span = value_range([target[:20], target[20:]])
    np.testing.assert_allclose(span, target.max(axis=0) - target.min(axis=0))
    np.testing.assert_allclose(rmse_percent(target, predicted, span),
                               100 * np.sqrt(((target - predicted) ** 2).mean(axis=0)) / span)
    assert np.isnan(rmse_percent(target, predicted, np.array([1.0, 0.0, 1.0]))[1])
    with pytest.raises(VispeechError, match="shapes differ"):
        mse(target, predicted[:, :2])


def test_scores_pool_frames_and_average_utterances():
    a_target, a_pred = np.array([[0.0], [1.0], [2.0]]), np.array([[0.0], [1.0], [1.0]])
    b_target, b_pred = np.array([[4.0], [2.0]]), np.array([[2.0], [2.0]])
    scores = score_channels(["x"], [a_target, b_target], [a_pred, b_pred])
    assert scores.frames == 5 and scores.utterances == 2
    assert scores.range[0] == 4.0  # over the whole set, not per utterance
    assert scores.mse[0] == pytest.approx((0 + 0 + 1 + 4 + 0) / 5)
    assert scores.rmse_percent[0] == pytest.approx(100 * np.sqrt(1.0) / 4)
    assert scores.utterance_mse[0] == pytest.approx((1 / 3 + 2) / 2)
    assert scores.utterance_rmse_percent[0] == pytest.approx((100 * np.sqrt(1 / 3) / 4 + 100 * np.sqrt(2) / 4) / 2)
    pooled = np.corrcoef([0, 1, 2, 4, 2], [0, 1, 1, 2, 2])[0, 1]
    assert scores.r[0] == pytest.approx(pooled)
    # b's prediction is constant: its r is undefined and left out of the utterance mean
    assert scores.utterance_r[0] == pytest.approx(np.corrcoef([0, 1, 2], [0, 1, 1])[0, 1])
    assert scores["x"]["mse"] == pytest.approx(1.0)


# -- closures ------------------------------------------------------------------------------

def _landmarks(gaps: np.ndarray) -> dict[str, np.ndarray]:
    """Eye corners 0.2 wide (72 px), inner lips ``gaps`` apart vertically (gap * 288 px)."""
    n = len(gaps)
    at = lambda x, y: np.tile([x, y, 0.0], (n, 1))  # noqa: E731
    lower = at(0.5, 0.6)
    lower[:, 1] += gaps
    return {"lm33": at(0.4, 0.3), "lm263": at(0.6, 0.3), "lm13": at(0.5, 0.6), "lm14": lower}


def test_the_lip_gap_is_measured_in_pixels_over_eye_distance():
    gaps = np.array([0.0, 0.0049, 0.0051, 0.02])
    ratio = lip_gap(_landmarks(gaps))
    np.testing.assert_allclose(ratio, gaps * 288 / 72)
    assert tracked_closed(_landmarks(gaps)).tolist() == [True, True, False, False]
    landmarks = _landmarks(gaps)
    landmarks["lm13"] = landmarks["lm13"] + [0.01, 0.0, 0.5]  # x counts (scaled by 360), z does not
    np.testing.assert_allclose(lip_gap(landmarks), np.hypot(3.6, gaps * 288) / 72)
    with pytest.raises(VispeechError, match="lm263"):
        lip_gap({k: v for k, v in _landmarks(gaps).items() if k != "lm263"})


def test_model_closure_is_relative_to_the_utterance_maximum():
    jaw = np.array([0.5, 0.3, 0.06, 0.1, 0.08])
    close = np.array([0.0, 0.0, 0.0, 0.05, 0.0])
    track = Track(np.column_stack([jaw, close]), ("jawOpen", "mouthClose"), FPS)
    assert model_closed(track).tolist() == [False, False, False, True, False]  # opening <= 0.05
    assert model_closed(Track(np.zeros((3, 1)), ("jawOpen",), FPS)).all()
    articulatory = Track(np.array([[0.1], [0.005], [0.01]]), ("lip_aperture",), FPS)
    assert model_closed(articulatory).tolist() == [False, True, True]
    with pytest.raises(VispeechError, match="jawOpen nor lip_aperture"):
        model_closed(Track(np.zeros((3, 1)), ("mouthPucker",), FPS))


def test_phone_frames_cover_the_phone_plus_one_frame():
    assert phone_frames(0.5, 0.7, FPS, 20).tolist() == [4, 5, 6, 7]
    assert phone_frames(1.01, 1.05, FPS, 20).tolist() == [9, 10, 11]  # shorter than a frame: its middle's
    assert phone_frames(0.0, 0.1, FPS, 20).tolist() == [0, 1]
    assert phone_frames(1.9, 2.0, FPS, 20).tolist() == [18, 19]


def test_count_closures_on_bilabials_and_speech_frames():
    phones = PhoneSequence([
        Phone("sil", 0.0, 0.5), Phone("P", 0.5, 0.7, 0), Phone("AA", 0.7, 1.0, 0), Phone("B", 1.0, 1.04, 0),
        Phone("AA", 1.04, 1.5, 0), Phone("M", 1.5, 1.7, 0), Phone("sil", 1.7, 2.0),
    ], "en", [Word("pabam", 0.5, 1.7)])
    speech = np.zeros(20, dtype=bool)
    speech[4:18] = True
    tracked = np.zeros(20, dtype=bool)
    tracked[[7, 10, 0]] = True  # P (in the +1 frame), B; frame 0 lies outside speech
    model = np.zeros(20, dtype=bool)
    model[[4, 15]] = True  # P (in the -1 frame); M, which the tracked lips do not close on
    counts = count_closures(phones, FPS, tracked, model, speech)
    assert counts == ClosureCounts(bilabials=3, tracked_closures=2, model_closures=1, speech_frames=14,
                                   tracked_closed_frames=2, model_closed_frames=2, onset_ms=(-300.0,),
                                   release_ms=(-300.0,))  # the model closes P 3 frames before the lips do
    assert counts.bilabial_rate == 50.0 and counts.tracked_closed_share == pytest.approx(100 * 2 / 14)
    assert not counts.passed
    total = counts + counts
    assert total.tracked_closures == 4 and total.bilabial_rate == 50.0 and total.onset_ms == (-300.0, -300.0)
    assert total.timing()["onset_median_ms"] == -300.0 and total.timing()["release_mean_abs_ms"] == 300.0
    assert np.isnan(ClosureCounts().timing()["onset_median_ms"])
    assert np.isnan(ClosureCounts().bilabial_rate)


def test_lip_vertex_error_through_a_linear_read_out():
    from vispeech.evaluation.metrics import lip_vertex_error

    rng = np.random.default_rng(0)
    scores = [rng.uniform(0, 1, (40, 3)) for _ in range(3)]
    mixing = rng.normal(0, 0.05, (3, 24))
    shapes = [(s @ mixing).reshape(40, 12, 2) for s in scores]
    shapes = [np.concatenate([x, np.zeros((40, 12, 1))], axis=2) for x in shapes]  # z is not used
    exact = lip_vertex_error(scores, scores, shapes)
    assert exact["floor"] < 1e-3 and exact["lve"] == pytest.approx(exact["floor"]) and exact["aperture_mae"] < 1e-3
    flat = lip_vertex_error(scores, [np.full_like(s, 0.5) for s in scores], shapes)
    assert flat["lve"] > 20 * exact["lve"] and flat["aperture_mae"] > 10 * exact["aperture_mae"]


def test_frames_are_classed_by_what_their_phone_does_to_the_lips():
    from vispeech.evaluation.closures import PHONE_CLASSES, frame_classes, phone_class

    assert [phone_class(s, "en") for s in ("AA", "M", "F", "T", "sil")] == list(PHONE_CLASSES)
    assert phone_class("v", "sv") == "labiodental" and phone_class("b", "sv") == "bilabial"
    phones = PhoneSequence([Phone("sil", 0.0, 0.2), Phone("M", 0.2, 0.4), Phone("AA", 0.4, 0.7)], "en")
    classes = frame_classes(phones, 10.0, 9)
    assert [PHONE_CLASSES[k] for k in classes] == ["silence"] * 2 + ["bilabial"] * 2 + ["vowel"] * 3 + ["silence"] * 2


# -- the report ----------------------------------------------------------------------------

def _utterance(name: str, seed: int, fps: float = FPS, repeats: int = 1) -> Utterance:
    """Silence, then B AA M IY P AA at 0.2 s each (``repeats`` times), then silence (0.5 s), tracked at
    ``fps``; tracked lips close on the bilabials and the 'recorded' track follows the phones. Frame 1
    was not tracked."""
    rng = np.random.default_rng(seed)
    symbols = ["B", "AA", "M", "IY", "P", "AA"] * repeats
    phones, t = [Phone("sil", 0.0, 0.5)], 0.5
    for s in symbols:
        phones.append(Phone(s, t, t + 0.2, 0))
        t += 0.2
    phones.append(Phone("sil", t, t + 0.5))
    sequence = PhoneSequence(phones, "en", [Word("bamipa", 0.5, t)])
    labels = sequence.frame_labels(fps)
    opening = np.array([0.0 if s in ("B", "M", "P", "sil") else 0.3 + 0.1 * rng.random() for s in labels])
    close = np.full(len(labels), 0.02)
    jaw = opening + close
    pucker = rng.random(len(labels))
    track = Track(np.column_stack([jaw, close, pucker, rng.random(len(labels))]),
                  ("jawOpen", "mouthClose", "mouthPucker", "eyeBlinkLeft"), fps)
    mask = np.ones(len(labels), dtype=bool)
    mask[1] = False
    return Utterance(id=name, text="bamipa", audio_path=Path("none.wav"), duration=sequence.duration,
                     track=track, words=list(sequence.words), phones=sequence,
                     landmarks=_landmarks(opening / 10), frame_mask=mask)


class Replay(Estimator):
    """Plays back the recorded track of whichever utterance's phones it is given."""

    family = "replay"
    data_free = True
    trainable = False
    defaults = {"offset": 0.0}
    channels = ("jawOpen", "mouthClose", "mouthPucker", "eyeBlinkLeft")

    def __init__(self, utterances, offset: float = 0.0):
        super().__init__(offset=offset)
        self.by_phones = {id(u.phones): u.track.select(self.channels) for u in utterances}

    def _fit(self, corpus, run):
        raise VispeechError("replay is data-free")

    def predict(self, phones, fps):
        track = self.by_phones[id(phones)]
        return Track(track.values + self.get_params()["offset"], track.channels, fps)

    def _learned_state(self):
        return None

    def _set_learned_state(self, state, arrays):
        raise ValueError("replay learns nothing")


@pytest.fixture
def corpus():
    utterances = [_utterance("a", 1), _utterance("b", 2)]
    return Corpus("synthetic", utterances, FPS, utterances[0].track.channels)


def test_a_perfect_model_scores_perfectly(corpus):
    evaluation = evaluate_models(corpus, {"replay": Replay(corpus), "shifted": Replay(corpus, 0.1)},
                                 postprocessing="none")
    perfect, shifted = evaluation["replay"], evaluation["shifted"]
    assert perfect.scores.channels == ("jawOpen", "mouthClose", "mouthPucker")
    # speech span 0.4 s .. 1.8 s: 15 frames each, less the untracked frame 1 (outside anyway)
    assert perfect.scores.frames == 30 and perfect.scores.utterances == 2
    np.testing.assert_allclose(perfect.scores.mse, 0.0, atol=1e-20)
    np.testing.assert_allclose(perfect.scores.r[[0, 2]], 1.0)
    assert np.isnan(perfect.scores.r[1])  # mouthClose is constant
    c = perfect.closures
    assert c.tracked_closures == c.bilabials == c.model_closures == 6
    assert c.model_closed_share == c.tracked_closed_share and c.passed
    np.testing.assert_allclose(shifted.scores.mse, 0.01)
    np.testing.assert_allclose(shifted.scores.r[[0, 2]], 1.0)
    np.testing.assert_allclose(shifted.scores.rmse_percent[[0, 2]], 100 * 0.1 / perfect.scores.range[[0, 2]])
    assert np.isnan(shifted.scores.rmse_percent[1])  # mouthClose has no range
    text, markdown = evaluation.to_text(), evaluation.to_markdown()
    assert "synthetic: 2 utterances, 30 speech frames at 10 fps, post-processing none" in text
    assert "replay   jawOpen" in text and "6/6" in text
    assert "| shifted | jawOpen | 0.01000 |" in markdown and "## Lip closures" in markdown


def test_each_utterance_is_animated_and_scored_at_its_own_frame_rate():
    utterances = [_utterance("a", 1), _utterance("b", 2, fps=2 * FPS)]
    corpus = Corpus("mixed", utterances, FPS, utterances[0].track.channels)
    replay = Replay(corpus)
    predicted = predict_on_frames(replay, corpus["b"], postprocessing="none")
    assert predicted.fps == 20.0 and predicted.n_frames == corpus["b"].track.n_frames == 44
    evaluation = evaluate_models(corpus, {"replay": replay}, channels=["jawOpen"], postprocessing="none")
    result = evaluation["replay"]
    assert evaluation.frame_rates == (10.0, 20.0)
    # speech span 0.4 s .. 1.8 s: 15 frames at 10 fps, 29 at 20 fps
    assert result.scores.frames == 44 and result.scores["jawOpen"]["r"] == pytest.approx(1.0)
    assert "mixed: 2 utterances, 44 speech frames at 10 and 20 fps" in evaluation.to_text()
    assert result.closures.tracked_closures == result.closures.model_closures == 6
    assert result.dynamics["lag_s"] == 0.0 and evaluation.recorded_dynamics == {
        key: value for key, value in result.dynamics.items() if key != "lag_s"}
    curves = [u.track["jawOpen"][scored_frames(u)] for u in utterances]
    assert evaluation.recorded_dynamics == motion_profile(curves, [10.0, 20.0])


def test_motion_and_lag_take_each_curves_frame_rate():
    rng = np.random.default_rng(3)
    seconds = np.arange(0, 4, 1 / 600)
    signal = np.convolve(rng.normal(size=len(seconds)), np.hanning(120), "same")  # about 5 Hz and slower
    slow, fast = signal[::24], signal[::20]  # the same curve at 25 and at 30 fps
    both = motion_profile([slow, fast], [25.0, 30.0])
    for key in ("velocity_rms", "acceleration_rms"):
        assert both[key] == pytest.approx(motion_profile([slow], 25.0)[key], rel=0.1)
        assert both[key] == pytest.approx(motion_profile([fast], 30.0)[key], rel=0.1)
    assert motion_profile([slow, fast], 25.0)["velocity_rms"] < 0.95 * both["velocity_rms"]
    late = [np.roll(slow, 5), np.roll(fast, 6)]  # 0.2 s late at either rate
    assert best_lag([slow, fast], late, [25.0, 30.0], max_seconds=0.3) == pytest.approx(0.2)
    assert best_lag([slow], late[:1], 25.0, max_seconds=0.3) == pytest.approx(0.2)
    with pytest.raises(VispeechError, match="1 frame rates for 2 curves"):
        motion_profile([slow, fast], [25.0])


def test_channels_default_to_shared_mouth_channels_with_jaw_first(corpus):
    baseline = create_model("baseline")
    assert model_channels(baseline, corpus) == ("jawOpen", "mouthClose", "mouthPucker")
    assert model_channels(baseline, corpus, ["mouthPucker"]) == ("jawOpen", "mouthPucker")
    with pytest.raises(VispeechError, match="no channel 'eyeBlinkRight'"):
        model_channels(baseline, corpus, ["eyeBlinkRight"])
    with pytest.raises(VispeechError, match="does not predict channel 'eyeBlinkLeft'"):
        model_channels(baseline, corpus, ["eyeBlinkLeft"])
    assert model_channels(Replay(corpus), corpus, ["eyeBlinkLeft"]) == ("jawOpen", "eyeBlinkLeft")


def test_data_free_models_close_on_bilabials_with_postprocessing(corpus):
    evaluation = evaluate_models(corpus, {"baseline": create_model("baseline")}, channels=["jawOpen"])
    closures = evaluation["baseline"].closures
    assert closures.bilabial_rate == 100.0
    raw = evaluate_models(corpus, {"baseline": create_model("baseline")}, channels=["jawOpen"],
                          postprocessing="none")
    assert raw["baseline"].scores.channels == ("jawOpen",)
    assert not np.allclose(raw["baseline"].scores.mse, evaluation["baseline"].scores.mse)


def test_predictions_are_sampled_on_the_recorded_frames(corpus):
    utterance = corpus[0]
    utterance.track = Track(utterance.track.values[:-3], utterance.track.channels, FPS, start_time=0.05)
    predicted = predict_on_frames(create_model("cohen-massaro"), utterance, postprocessing="none")
    direct = create_model("cohen-massaro").predict(utterance.phones, FPS)
    assert predicted.n_frames == utterance.track.n_frames and predicted.start_time == 0.05
    np.testing.assert_allclose(predicted["jawOpen"][2], (direct["jawOpen"][2] + direct["jawOpen"][3]) / 2)


def test_evaluation_needs_utterances_and_phones(corpus):
    with pytest.raises(VispeechError, match="no utterances"):
        evaluate_models(Corpus("empty", [], FPS, ()), {"baseline": create_model("baseline")})
    corpus[1].phones = None
    with pytest.raises(VispeechError, match="b has no phones"):
        evaluate_models(corpus, {"baseline": create_model("baseline")})


def test_plot_writes_a_png(corpus, tmp_path):
    path = plot_utterance(corpus[0], {"replay": Replay(corpus).predict(corpus[0].phones, FPS)}, tmp_path / "j.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(VispeechError, match="nothing to plot"):
        plot_utterance(corpus[0], {}, tmp_path / "k.png")
    assert not (tmp_path / "k.png").exists()


def test_a_long_utterance_is_plotted_in_rows_under_a_wrapped_title():
    """A 10.6-s utterance (natural speech runs to 30 s) used to be squeezed into one 10-inch row,
    its phone labels printed over each other and its title cut at the figure's edge."""
    from vispeech.evaluation.plots import ROW_SECONDS, utterance_figure

    long = _utterance("long", 3, repeats=8)
    long.text = " ".join(["bamipa"] * 40)
    corpus = Corpus("synthetic", [long], FPS, long.track.channels)
    figure = utterance_figure(long, {"replay": Replay(corpus).predict(long.phones, FPS)})
    rows = [a for a in figure.axes if a.get_ylabel() == "jawOpen"]
    assert len(rows) == math.ceil(long.duration / ROW_SECONDS) == 3
    assert [a.get_xlim() for a in rows] == [(4.0 * k, 4.0 * (k + 1)) for k in range(3)]
    labels = [t.get_text() for a in rows for top in a.child_axes for t in top.get_xticklabels()]
    assert len(labels) == 48 and labels[:2] == ["B", "AA\n"]  # each phone once, every other one raised
    title = figure.texts[0].get_text()
    assert title.startswith("long: bamipa") and len(title.splitlines()) == 3
    assert max(len(line) for line in title.splitlines()) <= 110


# -- the loudness floor ----------------------------------------------------------------------

def test_the_loudness_envelope_is_the_rms_level_per_frame():
    from vispeech.evaluation.floor import SILENT_DB, LoudnessFloor, loudness_envelope
    from vispeech.frontends.audio import AudioClip

    rate = 16000
    tone = 0.5 * np.sin(2 * np.pi * 1000 * np.arange(rate // 2) / rate)  # 0.5 s, RMS 0.5 / √2
    clip = AudioClip.from_array(np.concatenate([tone, np.zeros(rate // 2)]), rate)
    level = loudness_envelope(clip, 20.0)
    assert level.shape == (20,)
    np.testing.assert_allclose(level[1:9], 20 * np.log10(0.5 / np.sqrt(2)), atol=0.01)  # -9.03 dB
    assert level[10] == pytest.approx(10 * np.log10(0.125 / 2), abs=0.01)  # half a frame of tone, half silence
    np.testing.assert_array_equal(level[12:], SILENT_DB)
    jaw = LoudnessFloor().predict(clip, 20.0)
    assert jaw.channels == ("jawOpen",) and jaw.fps == 20.0
    np.testing.assert_allclose(jaw["jawOpen"][[2, 15]], [1 + 20 * np.log10(0.5 / np.sqrt(2)) / 60, 0.0], atol=1e-3)


def test_the_loudness_floor_is_scored_like_a_model(corpus):
    """Audio whose level follows the recorded jaw: the floor's jawOpen follows it too."""
    from vispeech.evaluation.floor import SILENT_DB, LoudnessFloor

    rate = 16000
    for utterance in corpus:
        times = np.arange(int(utterance.duration * rate)) / rate
        level = SILENT_DB * (1 - np.interp(times, utterance.track.times, utterance.track["jawOpen"]))
        utterance.audio = (np.sqrt(2) * 10 ** (level / 20) * np.sin(2 * np.pi * 500 * times)).astype(np.float32)
        utterance.sample_rate = rate
    floor = evaluate_models(corpus, {"floor": LoudnessFloor()}, channels=["jawOpen"])["floor"]
    assert floor.scores["jawOpen"]["r"] > 0.95 and floor.closures.tracked_closures == 6
    with pytest.raises(VispeechError, match="learns nothing"):
        LoudnessFloor().fit(corpus)


def _long_utterance(name: str, seconds: float, fps: float = 25.0, slow: bool = False) -> Utterance:
    """``seconds`` of one word over a smooth random jaw (2-6 Hz; ``slow``: a 4-s wave), tracked at ``fps``."""
    rng = np.random.default_rng(len(name) + int(seconds))
    n = int(seconds * fps)
    jaw = np.convolve(rng.normal(size=n + 20), np.hanning(9), "same")[10:-10]
    if slow:
        jaw = np.sin(2 * np.pi * np.arange(n) / (4 * fps))
    jaw = jaw - jaw.min()
    phones = PhoneSequence([Phone("AA", 0.0, n / fps, 0)], "en", [Word("ah", 0.0, n / fps)])
    track = Track(np.column_stack([jaw, np.zeros(n)]), ("jawOpen", "mouthClose"), fps)
    return Utterance(id=name, text="ah", audio_path=Path("none.wav"), duration=n / fps, track=track,
                     words=list(phones.words), phones=phones)


class Late(Replay):
    """Plays back the recorded track ``frames`` frames late, as from a picture that leads its sound."""

    defaults = {"offset": 0.0, "frames": 0}
    channels = ("jawOpen", "mouthClose")

    def __init__(self, utterances, frames: int = 0):
        Estimator.__init__(self, frames=frames)
        self.by_phones = {id(u.phones): u.track.select(self.channels) for u in utterances}

    def predict(self, phones, fps):
        track = self.by_phones[id(phones)]
        frames = self.get_params()["frames"]
        values = track.values[np.clip(np.arange(track.n_frames) - frames, 0, track.n_frames - 1)]
        return Track(values, track.channels, fps)


def test_sync_moves_predictions_by_each_long_utterances_lag():
    """The picture of a 10-s take leads its sound by 3 frames (a model in sync trails it): with
    ``sync`` every model's predictions are moved 3 frames earlier and score as if in sync; a 4-s
    take keeps its lag (too short to tell), and a lag beyond reach is not guessed."""
    utterances = [_long_utterance("long", 10.0), _long_utterance("short", 4.0)]
    corpus = Corpus("late", utterances, 25.0, ("jawOpen", "mouthClose"))
    late = Late(corpus, frames=3)
    plain = evaluate_models(corpus, {"late": late}, channels=["jawOpen"], postprocessing="none")
    synced = evaluate_models(corpus, {"late": late, "replay": Replay(corpus)}, channels=["jawOpen"],
                             postprocessing="none", sync=late)
    assert synced.sync == late.name and synced.lags == {"long": pytest.approx(3 / 25), "short": 0.0}
    assert plain.sync is None and plain.lags is None
    before, after = plain["late"].scores.per_utterance_r[:, 0], synced["late"].scores.per_utterance_r[:, 0]
    assert before[0] < 0.9 and after[0] == pytest.approx(1.0, abs=0.005) and after[1] == before[1]
    assert synced["replay"].scores.per_utterance_r[0, 0] < 0.9  # moved too: the lag is the recording's
    assert f"re-synced by {late.name}: predictions moved by each utterance's lag (median +60 ms, +0 to +120 ms; " \
           "1 of 2 moved)" in synced.to_text()
    from vispeech.evaluation.report_folder import evaluation_json

    assert evaluation_json(synced)["sync"] == {"model": late.name, "lags_s": {"long": 0.12, "short": 0.0}}
    assert "sync" not in evaluation_json(plain)
    moved = predict_on_frames(late, corpus["long"], "none", lag=3)
    np.testing.assert_array_equal(moved.values[:-3, 0], corpus["long"].track["jawOpen"][:-3])
    wave = Corpus("wave", [_long_utterance("wave", 10.0, slow=True)], 25.0, ("jawOpen", "mouthClose"))
    far = Late(wave, frames=12)  # 0.48 s late: beyond SYNC_REACH, r best at its edge
    assert evaluate_models(wave, {"far": far}, channels=["jawOpen"], postprocessing="none", sync=far).lags == {
        "wave": 0.0}
    assert evaluate_models(wave, {"near": Late(wave, frames=5)}, channels=["jawOpen"], postprocessing="none",
                           sync=Late(wave, frames=5)).lags == {"wave": pytest.approx(0.2)}
    with pytest.raises(VispeechError, match="has no jawOpen to re-sync"):
        evaluate_models(corpus, {"late": late}, channels=["jawOpen"], sync=Pucker(corpus))


def test_sync_moves_the_phones_with_the_predictions_when_it_counts_closures():
    """The picture of a 10-s take leads its sound by 3 frames, its lips closing 3 frames before
    each /m/ is heard. Unsynced, no tracked closure falls on its /m/; with ``sync`` the phones are
    moved with the predictions, onto the picture: every closure counts, and the model (the take
    played 3 frames late, moved back) makes each one."""
    fps, n = 25.0, 250
    utterance = _long_utterance("long", 10.0)
    closes = np.arange(20, n - 20, 25)  # an /m/ heard at frames c, c+1
    phones, words, time = [], [], 0.0
    for k, c in enumerate(closes):
        phones += [Phone("AA", time, c / fps, k), Phone("M", c / fps, (c + 2) / fps, k)]
        words.append(Word("am", time, (c + 2) / fps))
        time = (c + 2) / fps
    phones.append(Phone("AA", time, n / fps, len(closes)))
    words.append(Word("ah", time, n / fps))
    sequence = PhoneSequence(phones, "en", words)
    jaw = utterance.track["jawOpen"] + 0.2
    gap = np.full(n, 5.0)
    for c in closes:  # the picture: closed at c - 3 (its own frames c-4 .. c-2)
        jaw[c - 4 : c - 1], gap[c - 4 : c - 1] = 0.0, 0.0
    eyes = {"lm33": np.tile([0.3, 0.5, 0.0], (n, 1)), "lm263": np.tile([0.7, 0.5, 0.0], (n, 1))}
    lips = {"lm13": np.column_stack([np.full(n, 0.5), 0.6 + gap / 288, np.zeros(n)]),
            "lm14": np.tile([0.5, 0.6, 0.0], (n, 1))}
    utterance = Utterance(id="long", text="am", audio_path=Path("none.wav"), duration=n / fps,
                          track=Track(np.column_stack([jaw, np.zeros(n)]), ("jawOpen", "mouthClose"), fps),
                          words=words, phones=sequence, landmarks={**eyes, **lips})
    corpus = Corpus("late", [utterance], fps, ("jawOpen", "mouthClose"))
    late = Late(corpus, frames=3)
    plain = evaluate_models(corpus, {"late": late}, channels=["jawOpen"], postprocessing="none")["late"].closures
    synced = evaluate_models(corpus, {"late": late}, channels=["jawOpen"], postprocessing="none", sync=late)
    assert synced.lags == {"long": pytest.approx(3 / fps)}
    counts = synced["late"].closures
    assert plain.tracked_closures == 0 and counts.bilabials == len(closes)
    assert counts.tracked_closures == counts.model_closures == len(closes)
    # the per-phone-class errors label the frames by the phones moved alike
    from vispeech.evaluation.closures import PHONE_CLASSES
    from vispeech.evaluation.report import _phone_classes

    mask = [np.ones(n, dtype=bool)]
    heard, seen = _phone_classes(corpus, mask), _phone_classes(corpus, mask, [3])
    bilabial = PHONE_CLASSES.index("bilabial")
    assert np.array_equal(seen[:-3], heard[3:]) and (heard == bilabial).sum() == 2 * len(closes)


class Pucker(Late):
    channels = ("mouthPucker",)


@pytest.mark.parametrize(("epochs", "span", "ticks", "scale"), [
    (1, 1.2, [1.0], "linear"),  # one epoch: the tick 1, not 0.96 to 1.04
    (4, 1.5, [1.0, 2.0, 3.0, 4.0], "linear"),  # losses within 3 times: no log scale of 6 × 10⁻¹
    (40, 40.0, None, "log"),
])
def test_a_loss_curve_has_whole_epochs_and_a_log_scale_only_for_a_wide_range(epochs, span, ticks, scale):
    from vispeech.evaluation.plots import history_figure
    from vispeech.models.history import TrainingHistory

    train = list(np.geomspace(0.5 * span, 0.5, epochs))
    history = TrainingHistory(train, [1.1 * v for v in train], [1e-3] * epochs, [1.0] * epochs, epochs)
    axes = history_figure(history).axes[0]
    shown = [t for t in axes.get_xticks() if axes.get_xlim()[0] <= t <= axes.get_xlim()[1]]
    assert all(float(t).is_integer() for t in shown) and (ticks is None or shown == ticks), shown
    assert axes.get_yscale() == scale


def test_evaluation_helpers_refuse_no_channels_and_a_frame_rate_of_zero(corpus):
    """Found by the API's QA: channels=[] scored jawOpen alone, silently; best_lag and
    motion_profile at 0 fps divided by zero, at -25 fps gave numbers."""
    with pytest.raises(VispeechError, match="no channels to score"):
        evaluate_models(corpus, {"baseline": create_model("baseline")}, channels=[])
    curve = np.sin(np.linspace(0, 6, 50))
    for fps in (0, -25, float("nan")):
        with pytest.raises(VispeechError, match="fps must be"):
            best_lag([curve], [curve], fps)
        with pytest.raises(VispeechError, match="fps must be"):
            motion_profile([curve], fps)
    with pytest.raises(VispeechError, match="num_threads must be a whole number of 1 or more"):
        create_model("ohman").fit(corpus, num_threads=-1)
