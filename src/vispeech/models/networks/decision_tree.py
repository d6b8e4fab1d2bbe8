"""Sliding-window decision-tree regression (Kim et al. 2015), Taylor et al.'s (2017) baseline.

Like the sliding-window networks (:mod:`vispeech.models.networks.sliding_window`), a window of
``input_window`` (Kx = 11) frames of phone inputs predicts ``output_window`` (Ky = 5) frames of
every target channel, windows slide one frame and every frame's Ky predictions are averaged;
here one regression tree (scikit-learn's CART, squared error, at least ``min_leaf`` = 10
windows per leaf) maps the flattened window to the flattened output window.

The fitted tree is kept as arrays (children, split feature and threshold, leaf values) and
predicted with NumPy alone: scikit-learn is needed to fit (the ``train`` extra), not to predict.
"""

from __future__ import annotations

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.contract import Estimator
from vispeech.models.fitting import FitRun, training_split
from vispeech.models.history import TrainingHistory
from vispeech.models.networks.encoding import InputEncoding
from vispeech.models.networks.kernels import overlap_average, padded_windows
from vispeech.models.networks.network import check_training_params, check_windows
from vispeech.motion.arkit import MOUTH_CHANNELS
from vispeech.motion.track import Track


class DecisionTreeRegression(Estimator[PhoneSequence]):
    """Kim et al.'s sliding-window decision tree; hyper-parameters in :attr:`defaults`."""

    family = "sliding-window-dtree"
    defaults = {
        "input_window": 11,
        "output_window": 5,
        "min_leaf": 10,
        "inputs": "phones",
        "linguistic": False,
        "targets": "all",
        "fps": None,
        "language": None,
        "seed": 0,
    }

    def _check_params(self) -> None:
        p = self._params
        for key in ("input_window", "output_window", "min_leaf"):
            if not isinstance(p[key], int) or p[key] < 1:
                raise VispeechError(f"{key} must be a whole number of 1 or more, got {p[key]!r}")
        check_windows(p["input_window"], p["output_window"])
        check_training_params(p)
        InputEncoding(p["inputs"], p["language"] or "en", p["linguistic"], False)

    @property
    def channels(self) -> tuple[str, ...]:
        return getattr(self, "outputs_", ()) or (
            () if self._params["targets"] == "all" else tuple(self._params["targets"])
        )

    @property
    def frame_rate(self) -> float | None:
        return getattr(self, "fps_", None)

    @property
    def lookahead(self) -> int:
        return (self._params["input_window"] + self._params["output_window"]) // 2 - 1

    def _fit(self, corpus, run: FitRun) -> DecisionTreeRegression:
        """Grow the tree on every window of the training utterances. ``history_`` holds one
        "epoch": the mean squared error of the fitted frames on the training split and, when there
        is one, on the validation split, and the seconds it took."""
        import time

        from sklearn.tree import DecisionTreeRegressor

        run.in_one_go(self.family)
        started = time.perf_counter()
        train, validation = training_split(corpus)
        p = self._params
        first = train[0]
        self.fps_ = float(p["fps"] or first.track.fps)
        available = tuple(first.track.channels)
        wanted = p["targets"]
        self.outputs_ = tuple(c for c in MOUTH_CHANNELS if c in available) if wanted == "all" else tuple(wanted)
        missing = [c for c in self.outputs_ if c not in available]
        if missing or not self.outputs_:
            raise VispeechError(f"the corpus tracks lack the target channels {', '.join(missing) or 'of the mouth'}")
        language = p["language"] or getattr(corpus, "language", None) or first.phones.language
        self.encoding_ = InputEncoding(p["inputs"], language, p["linguistic"], False)
        x, y = [], []
        ky = p["output_window"]
        for utterance in train:
            inputs, targets = self._example(utterance)
            x.append(padded_windows(inputs, p["input_window"], ky).reshape(-1, p["input_window"] * inputs.shape[1]))
            padded = np.pad(targets, ((ky - 1, ky - 1), (0, 0)), mode="edge")
            y.append(
                np.lib.stride_tricks.sliding_window_view(padded, ky, axis=0)[: len(x[-1])]
                .transpose(0, 2, 1)
                .reshape(len(x[-1]), -1)
            )
        tree = DecisionTreeRegressor(min_samples_leaf=p["min_leaf"], random_state=p["seed"]).fit(
            np.concatenate(x), np.concatenate(y)
        )
        t = tree.tree_
        self.tree_ = {
            "left": t.children_left.astype(np.int32),
            "right": t.children_right.astype(np.int32),
            "feature": t.feature.astype(np.int32),
            "threshold": t.threshold.astype(np.float64),
            "value": t.value[:, :, 0].astype(np.float64),
        }
        losses = [self._mse(split) if split else None for split in (train, validation)]
        assert losses[0] is not None  # training_split refuses an empty train split
        self.history_ = TrainingHistory([losses[0]], [losses[1]], [0.0], [time.perf_counter() - started], 1)
        return self

    def _example(self, utterance) -> tuple[np.ndarray, np.ndarray]:
        """``(inputs, targets)`` of one utterance at the model's frame rate."""
        track = utterance.track.select(self.outputs_)
        if track.fps != self.fps_:
            track = track.resample(self.fps_)
        return self.encoding_.encode(utterance.phones, self.fps_, n_frames=track.n_frames), track.values

    def _mse(self, utterances) -> float:
        """Mean squared error of the frames predicted for ``utterances`` (all channels)."""
        errors = []
        for utterance in utterances:
            inputs, targets = self._example(utterance)
            errors.append((self._frames(inputs) - targets) ** 2)
        return float(np.mean(np.concatenate(errors)))

    def predict(self, inputs: PhoneSequence, fps: float) -> Track:
        """Tracks of ``inputs.n_frames(fps)`` frames: the overlap-averaged tree predictions at the
        model's frame rate, resampled to ``fps``."""
        self.check_fitted()
        self.check_inputs(inputs, fps)
        self.encoding_.check(inputs)
        track = Track(self._frames(self.encoding_.encode(inputs, self.fps_)), self.outputs_, self.fps_)
        n = inputs.n_frames(fps)
        return track if fps == self.fps_ and track.n_frames == n else track.resample(fps, n_frames=n)

    def _frames(self, rows: np.ndarray) -> np.ndarray:
        """Frames (rows × outputs, clipped to 0..1) for input rows: every window through the tree,
        overlap-averaged."""
        p = self._params
        windows = padded_windows(rows, p["input_window"], p["output_window"])
        out = self._leaf_values(windows.reshape(len(windows), -1)).reshape(len(windows), p["output_window"], -1)
        return np.clip(overlap_average(out, len(rows)), 0.0, 1.0)

    def _leaf_values(self, x: np.ndarray) -> np.ndarray:
        """The tree's prediction for each row of ``x``: every row walks down a level per step."""
        tree = self.tree_
        node = np.zeros(len(x), dtype=np.int64)
        rows = np.arange(len(x))
        while True:
            inner = tree["left"][node] >= 0
            if not inner.any():
                return tree["value"][node]
            here = node[inner]
            go_left = x[rows[inner], tree["feature"][here]] <= tree["threshold"][here]
            node[inner] = np.where(go_left, tree["left"][here], tree["right"][here])

    @property
    def leaves(self) -> int:
        """Leaves of the fitted tree."""
        return int((self.tree_["left"] < 0).sum())

    def _learned_state(self) -> tuple[dict, dict[str, np.ndarray]] | None:
        if not hasattr(self, "tree_"):
            return None
        return (
            {
                "encoding": self.encoding_.to_dict(),
                "outputs": list(self.outputs_),
                "fps": self.fps_,
                "history": self.history_.to_dict(),
            },
            {f"tree.{k}": v for k, v in self.tree_.items()},
        )

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        self.encoding_ = InputEncoding.from_dict(state["encoding"])
        self.outputs_ = tuple(state["outputs"])
        self.fps_ = float(state["fps"])
        self.history_ = TrainingHistory.from_dict(state["history"])
        self.tree_ = {k[5:]: v for k, v in arrays.items() if k.startswith("tree.")}
        if set(self.tree_) != {"left", "right", "feature", "threshold", "value"}:
            raise VispeechError("a decision tree model needs tree.left, .right, .feature, .threshold and .value")
