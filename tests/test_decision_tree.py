"""Taylor et al.'s decision-tree baseline: Kim et al.'s sliding-window regression tree."""

from __future__ import annotations

import numpy as np
import pytest
from test_contract import FPS, sentence, tiny_corpus

from vispeech.models.networks.kernels import padded_windows
from vispeech.models.registry import create_model, load_model

pytest.importorskip("sklearn")  # fitting needs scikit-learn (the train extra); predicting does not


@pytest.fixture(scope="module")
def fitted():
    return create_model("sliding-window-dtree", min_leaf=2, targets=["jawOpen", "mouthPucker"]).fit(tiny_corpus(range(8)))


def test_the_numpy_walk_is_scikit_learns_tree(fitted):
    from sklearn.tree import DecisionTreeRegressor

    p = fitted.get_params()
    rows = fitted.encoding_.encode(sentence(60), fitted.fps_)
    x = padded_windows(rows, p["input_window"], p["output_window"]).reshape(-1, p["input_window"] * rows.shape[1])
    assert fitted.leaves > 10
    # the same tree grown again by scikit-learn on the same windows predicts the same leaves
    xs, ys = [], []
    for utterance in tiny_corpus(range(8)):
        inputs, targets = fitted._example(utterance)
        xs.append(padded_windows(inputs, 11, 5).reshape(-1, 11 * inputs.shape[1]))
        padded = np.pad(targets, ((4, 4), (0, 0)), mode="edge")
        ys.append(np.lib.stride_tricks.sliding_window_view(padded, 5, axis=0)[:len(xs[-1])].transpose(0, 2, 1)
                  .reshape(len(xs[-1]), -1))
    tree = DecisionTreeRegressor(min_samples_leaf=2, random_state=0).fit(np.concatenate(xs), np.concatenate(ys))
    np.testing.assert_allclose(fitted._leaf_values(x), tree.predict(x), atol=1e-12)


def test_it_learns_its_training_targets_and_min_leaf_smooths(fitted):
    corpus = tiny_corpus(range(8))
    close = [np.corrcoef(fitted.predict(u.phones, FPS)["jawOpen"], u.track["jawOpen"])[0, 1] for u in corpus]
    assert np.mean(close) > 0.95
    coarse = create_model("sliding-window-dtree", min_leaf=200, targets=["jawOpen", "mouthPucker"]).fit(corpus)
    assert coarse.leaves < fitted.leaves / 4
    assert coarse.history_.train_loss[0] > 2 * fitted.history_.train_loss[0]


def test_saved_and_loaded_it_predicts_alike_without_scikit_learn(fitted, tmp_path, monkeypatch):
    import sys

    folder = fitted.save(tmp_path / "tree")
    monkeypatch.setitem(sys.modules, "sklearn", None)  # prediction needs NumPy only
    again = load_model(folder)
    for seed in (61, 62):
        np.testing.assert_array_equal(again.predict(sentence(seed), FPS).values, fitted.predict(sentence(seed), FPS).values)
