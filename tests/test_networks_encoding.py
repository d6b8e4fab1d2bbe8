"""Input encodings of the networks and the sliding-window overlap averaging."""

import numpy as np
import pytest
import torch

from vispeech import Phone, PhoneSequence, VispeechError
from vispeech.models.networks.encoding import LINGUISTIC_NAMES, InputEncoding
from vispeech.models.networks.modules import overlap_average
from vispeech.phonetics.features import FEATURE_NAMES, phone_features
from vispeech.phonetics.inventory import get_inventory

ENGLISH = PhoneSequence(
    [Phone("B", 0.1, 0.2), Phone("AA", 0.2, 0.4, stress=1), Phone("T", 0.45, 0.5)], "en"
)  # a gap before B and between AA and T


def test_phone_one_hot_marks_the_covering_phone_and_silence_in_gaps():
    encoding = InputEncoding("phones", "en")
    x = encoding.encode(ENGLISH, 25.0)
    symbols = get_inventory("en").symbols
    assert x.shape == (ENGLISH.n_frames(25.0), len(symbols)) == (13, 41)
    assert np.all(x.sum(axis=1) == 1)
    labels = [symbols[i] for i in x.argmax(axis=1)]
    assert labels == ["sil"] * 3 + ["B"] * 2 + ["AA"] * 5 + ["sil"] * 2 + ["T"]


def test_feature_encoding_is_the_phone_feature_vector_with_stress():
    x = InputEncoding("features").encode(ENGLISH, 25.0)
    assert x.shape == (13, len(FEATURE_NAMES))
    np.testing.assert_array_equal(x[6], phone_features("AA", "en", stress=1).astype(np.float32))
    swedish = PhoneSequence([Phone("A:", 0.0, 0.2), Phone("rt", 0.2, 0.3)], "sv")
    y = InputEncoding("features").encode(swedish, 50.0)
    assert y.shape == (15, len(FEATURE_NAMES))
    assert y[12, FEATURE_NAMES.index("retroflex")] == 1


def test_phone_encoding_refuses_another_language():
    swedish = PhoneSequence([Phone("A:", 0.0, 0.2)], "sv")
    with pytest.raises(VispeechError, match="inputs='features'"):
        InputEncoding("phones", "en").encode(swedish, 25.0)
    with pytest.raises(VispeechError, match="input kind"):
        InputEncoding("letters")


def test_linguistic_indicators_and_position():
    encoding = InputEncoding("phones", "en", linguistic=True, position=True)
    x = encoding.encode(ENGLISH, 25.0)
    assert x.shape[1] == encoding.size == 41 + len(LINGUISTIC_NAMES) + 1
    names = encoding.names

    def on(frame):
        return {n for n, v in zip(names, x[frame]) if v and n != "position"}

    assert on(3) == {"phone:B", "is_consonant", "is_bilabial", "is_stop", "is_voiced_consonant", "sil>labial"}
    assert on(4) == {"phone:B", "is_consonant", "is_bilabial", "is_stop", "is_voiced_consonant"}
    assert "labial>unround" in on(5) and "is_open_vowel" in on(5) and "is_back_vowel" in on(5)
    assert "unround>sil" in on(10) and "sil>coronal" in on(12)
    position = x[:, -1]
    np.testing.assert_allclose(position[5:10], [0.0, 0.2, 0.4, 0.6, 0.8], atol=1e-6)  # AA 0.2-0.4 s


def test_encoding_frame_by_frame_equals_encoding_at_once():
    encoding = InputEncoding("features", linguistic=True, position=True)
    whole = encoding.encode(ENGLISH, 25.0)
    pieces = [encoding.encode(ENGLISH, 25.0, n_frames=k + 1, start_frame=k) for k in range(len(whole))]
    np.testing.assert_array_equal(np.concatenate(pieces), whole)


def test_overlap_average_is_the_mean_of_every_prediction_of_a_frame():
    n_frames, ky = 7, 3
    windows = n_frames + ky - 1
    # window w predicts frames w - ky + 1 .. w; give each prediction the value frame + 10·k
    frame = torch.arange(windows)[:, None] - (ky - 1) + torch.arange(ky)[None, :]
    out = (frame + 10 * torch.arange(ky)[None, :]).double()[:, :, None]
    averaged = overlap_average(out, n_frames)[:, 0]
    np.testing.assert_allclose(averaged.numpy(), np.arange(n_frames) + 10.0)  # mean of 0, 10, 20
