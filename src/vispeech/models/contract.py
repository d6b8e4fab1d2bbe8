"""The model contract: what every control model is and does, whatever its family or input.

A control model is an estimator in scikit-learn's sense:

- the constructor stores *hyper-parameters* only (the training budget included), given by
  keyword over the family's :attr:`Estimator.defaults`; :meth:`~Estimator.get_params` returns
  them and never changes after :meth:`~Estimator.fit`;
- :meth:`~Estimator.fit` ``(corpus, *, progress=None) -> self`` learns from a corpus (an object
  with ``split("train")`` and ``split("validation")``, or any iterable of utterances with
  ``.phones`` and ``.track``, all of them used for training); what it learns lives in
  attributes whose names end in ``_``; data-free families (rules with authored parameters)
  are ready without it;
- :meth:`~Estimator.predict` ``(inputs, fps) -> Track`` animates one utterance's inputs
  (a :class:`~vispeech.alignment.phones.PhoneSequence` for the phone families; audio
  families take audio through the same call, and :meth:`~Estimator.predict_with_closures`
  also gives the bilabials they hear); :attr:`~Estimator.is_fitted` says whether it can;
- :attr:`~Estimator.lookahead` is how many frames of input after frame t a stream needs
  before it gives frame t, and :meth:`~Estimator.stream` predicts incrementally as inputs
  arrive (:class:`ModelStream`);
- :meth:`~Estimator.save` and :meth:`Estimator.load` are the same for every family: a folder
  with ``config.json`` (``format``, ``version``, ``name``, ``family``, ``input``, ``params``,
  the learned ``state`` as JSON, the names of the learned ``arrays`` and the recommended
  ``postprocessing`` preset) and, when there are arrays, ``weights.safetensors``. No pickle.

A model is known by one :attr:`~Estimator.name`: its family's for a fresh one, the shipped
name (``grid-tdnn``) for a shipped one, and whatever name it was saved under otherwise.
"""

from __future__ import annotations

import copy
import json
import math
import os
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence, first_frame
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.motion.track import Track

FORMAT = "vispeech-model"
FORMAT_VERSION = 2
"""Version of the saved-model folder format; loading refuses others."""
CONFIG = "config.json"
WEIGHTS = "weights.safetensors"
FOLDER_NAMES = (CONFIG, WEIGHTS, "training_state.json", "training_state.safetensors", "loss_curve.png", "checkpoint")
"""What a model folder may hold (beside the model: a network's training state, and ``vispeech
train``'s loss curve and checkpoint sub-folder); :meth:`Estimator.save` replaces a folder
holding only these."""
INPUT_KINDS = ("phones", "audio")

_Self = TypeVar("_Self", bound="Estimator")


class Estimator(ABC):
    """Base of every control model; see the module docstring for the contract."""

    family: ClassVar[str] = ""
    """The registered name of the family (``cohen-massaro``, ``tdnn-beskow``, ...)."""
    input_kind: ClassVar[str] = "phones"
    """What :meth:`predict` takes: ``"phones"`` or ``"audio"``."""
    data_free: ClassVar[bool] = False
    """True when the family predicts from its hyper-parameters alone (no fit needed)."""
    trainable: ClassVar[bool] = True
    """False when :meth:`fit` has nothing to learn (authored rules)."""
    defaults: ClassVar[Mapping[str, Any]] = {}
    """Every hyper-parameter with its default value."""

    def __init__(self, **params: Any) -> None:
        unknown = sorted(set(params) - set(self.defaults))
        if unknown:
            known = ", ".join(sorted(self.defaults)) or "none"
            raise VispeechError(f"model {self.family} has no parameter {unknown[0]!r} (it has: {known})")
        self._params = {key: _plain(params.get(key, value)) for key, value in self.defaults.items()}
        self.name = self.family
        self._check_params()

    def _check_params(self) -> None:
        """Raise :class:`VispeechError` on a bad hyper-parameter value."""

    def get_params(self) -> dict[str, Any]:
        """A copy of the hyper-parameters."""
        return copy.deepcopy(self._params)

    # -- what every family defines ---------------------------------------------------------

    @property
    @abstractmethod
    def channels(self) -> tuple[str, ...]:
        """The channels :meth:`predict` gives, in order."""

    @property
    def is_fitted(self) -> bool:
        """Whether :meth:`predict` can run: always for data-free families, else after :meth:`fit`."""
        return self.data_free or self._has_learned()

    def _has_learned(self) -> bool:
        """Whether fitting (or loading) left learned attributes (public names ending in ``_``)."""
        return any(name.endswith("_") and not name.startswith("_") for name in vars(self))

    @property
    def frame_rate(self) -> float | None:
        """The frame rate the model predicts at before resampling (``None``: at whatever is asked)."""
        return None

    @property
    def lookahead(self) -> int:
        """Frames of input after frame t that :meth:`stream` waits for before giving frame t, at
        :attr:`frame_rate` (the stream's when that is ``None``). A :class:`ModelStream` states
        its own in its frames."""
        return 2

    @property
    def postprocessing(self) -> str:
        """The post-processing preset this model recommends (:data:`vispeech.targets.presets.PRESETS`)."""
        return "learned-jaw" if self._has_learned() else "authored"

    @abstractmethod
    def fit(self: _Self, corpus, *, progress: bool | None = None) -> _Self:
        """Learn from ``corpus``; returns ``self``. ``progress``: bars and lines on stderr
        (``None``: when stderr is a terminal)."""

    @abstractmethod
    def predict(self, inputs: PhoneSequence, fps: float) -> Track:
        """A track of ``inputs.n_frames(fps)`` frames from time 0 over :attr:`channels`."""

    def predict_with_closures(self, inputs: Any, fps: float) -> tuple[Track, PhoneSequence | None]:
        """:meth:`predict`'s track and the bilabials the model hears in audio, as phones that
        post-processing may shut the lips on; ``None`` (the default) for a model that hears none."""
        return self.predict(inputs, fps), None

    def stream(self, language: str, fps: float) -> ModelStream:
        """An incremental prediction for phones of ``language`` as they arrive, at ``fps``."""
        self.check_fitted()
        return WindowStream(self, language, fps)

    # -- learned state, for save and load --------------------------------------------------

    @abstractmethod
    def _learned_state(self) -> tuple[dict, dict[str, np.ndarray]] | None:
        """What fitting learned, as JSON and named arrays (``None`` before fitting)."""

    @abstractmethod
    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        """Take over a state given by :meth:`_learned_state` (raise :class:`VispeechError` if it does not fit)."""

    def check_fitted(self) -> None:
        """Raise :class:`VispeechError` unless :attr:`is_fitted`."""
        if not self.is_fitted:
            raise VispeechError(f"model {self.name} is not trained: fit it on a corpus (vispeech train) "
                                "or load a trained one")

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model into folder ``path`` as a whole; returns the folder.

        The new folder replaces ``path`` in one step (:func:`vispeech.files.atomic_output_dir`):
        an existing folder is replaced only when it holds nothing but :data:`FOLDER_NAMES`,
        otherwise :class:`VispeechError`.
        """
        with atomic_output_dir(path, replaces=FOLDER_NAMES) as staging:
            self._write_files(staging)
        return Path(path)

    def _write_files(self, folder: Path) -> None:
        """Write ``config.json`` (and ``weights.safetensors``) into ``folder``, which exists: the
        staging folder of :meth:`save` or of a checkpoint that adds files of its own."""
        from safetensors.numpy import save as to_safetensors

        learned = self._learned_state()
        state, arrays = learned if learned is not None else (None, {})
        config = {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "name": self.name,
            "family": self.family,
            "input": self.input_kind,
            "vispeech": _package_version(),
            "channels": list(self.channels) if self.is_fitted else None,
            "params": self.get_params(),
            "state": state,
            "arrays": sorted(arrays),
            "postprocessing": self.postprocessing,
        }
        (folder / CONFIG).write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
        if arrays:
            tensors = {key: np.ascontiguousarray(value) for key, value in arrays.items()}
            (folder / WEIGHTS).write_bytes(to_safetensors(tensors))

    @classmethod
    def load(cls: type[_Self], path: str | os.PathLike) -> _Self:
        """Read a folder written by :meth:`save` into a model of this family (or a subclass's).

        Raises :class:`VispeechError` if the folder is missing or corrupt or holds another family.
        """
        folder = Path(path)
        config = read_config(folder)
        if config["family"] != cls.family:
            raise VispeechError(f"{folder} holds a {config['family']} model, not a {cls.family} model")
        return cls._from_config(folder, config)

    @classmethod
    def _from_config(cls: type[_Self], folder: Path, config: dict) -> _Self:
        try:
            model = cls(**config["params"])
        except TypeError as exc:
            raise VispeechError(f"corrupt model config in {folder}: {exc}") from None
        model.name = config["name"]
        if config["input"] != model.input_kind:
            raise VispeechError(f"{folder / CONFIG} says input {config['input']}, but {model.family} takes {model.input_kind}")
        if config["state"] is None and config["arrays"]:
            raise VispeechError(f"{folder / CONFIG} lists learned arrays but no learned state")
        if config["state"] is not None:
            arrays = _read_arrays(folder / WEIGHTS, config["arrays"])
            try:
                model._set_learned_state(config["state"], arrays)
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                raise VispeechError(f"corrupt model state in {folder}: {exc}") from None
        if config["channels"] is not None and list(model.channels) != config["channels"]:
            raise VispeechError(f"{folder / CONFIG} lists channels that do not match the {model.family} model's")
        if config["postprocessing"] != model.postprocessing:
            raise VispeechError(f"{folder / CONFIG} recommends post-processing {config['postprocessing']!r}, "
                                f"but a {'fitted' if model.is_fitted else 'new'} {model.family} model recommends "
                                f"{model.postprocessing!r}")
        return model

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} ({self.family}{'' if self.is_fitted else ', not fitted'})>"


def _plain(value: Any) -> Any:
    """``value`` as JSON gives it back (tuples as lists, paths as strings, NumPy scalars as
    numbers), so that :meth:`Estimator.get_params` is the same before saving and after loading."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, np.generic):
        return value.item()
    return copy.deepcopy(value)


def read_config(folder: Path) -> dict:
    """The checked ``config.json`` of a saved-model folder."""
    path = folder / CONFIG
    if not path.is_file():
        raise VispeechError(f"no saved model at {folder} ({CONFIG} missing)")
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
        if config.get("format") != FORMAT:
            raise ValueError(f"not a {FORMAT} folder")
        if config.get("version") != FORMAT_VERSION:
            raise ValueError(f"format version {config.get('version')!r}; this vispeech reads {FORMAT_VERSION}")
        for key, kind in (("name", str), ("family", str), ("params", dict), ("arrays", list),
                          ("postprocessing", str)):
            if not isinstance(config.get(key), kind):
                raise ValueError(f"{key} must be a {kind.__name__}")
        if config.get("input") not in INPUT_KINDS or not isinstance(config.get("state"), dict | None):
            raise ValueError("input must be phones or audio and state an object or null")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError) as exc:
        raise VispeechError(f"corrupt model config {path}: {exc}") from None
    return config


def _read_arrays(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    if not names:
        return {}
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    try:
        arrays = load_file(path)
    except (OSError, SafetensorError, ValueError) as exc:
        raise VispeechError(f"cannot read model weights {path}: {exc}") from None
    if sorted(arrays) != sorted(names):
        raise VispeechError(f"{path} holds arrays {sorted(arrays)[:4]}..., its config lists others")
    return arrays


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vispeech")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


@dataclass(frozen=True)
class Splits:
    """Training data given as lists, read by :meth:`Estimator.fit` as a corpus with splits
    (``train`` to learn from, ``validation`` to stop early on)."""

    train: Sequence
    validation: Sequence = ()

    def split(self, name: str) -> list:
        """The utterances of split ``name`` (``train`` or ``validation``; ``test`` is empty)."""
        return list({"train": self.train, "validation": self.validation}.get(name, ()))


def training_split(corpus) -> tuple[list, list]:
    """``(train, validation)`` utterances of what :meth:`Estimator.fit` is given.

    A corpus with splits gives its ``train`` and ``validation`` splits; any other iterable
    of utterances trains on all of it with no validation. Raises :class:`VispeechError` on an
    empty training set or an utterance without phones.
    """
    if hasattr(corpus, "split"):
        train, validation = list(corpus.split("train")), list(corpus.split("validation"))
    elif isinstance(corpus, Iterable) and not isinstance(corpus, str | bytes):
        train, validation = list(corpus), []
    else:
        raise VispeechError("fit needs a corpus: an iterable of utterances with .phones and .track")
    if not train:
        raise VispeechError("cannot fit on an empty corpus")
    for utterance in train + validation:
        if getattr(utterance, "phones", None) is None:
            raise VispeechError(f"utterance {getattr(utterance, 'id', '?')} has no phones: align the corpus first")
    return train, validation


def show_progress(progress: bool | None) -> bool:
    """What ``progress=None`` means: bars and lines when stderr is a terminal."""
    if progress is None:
        import sys

        return sys.stderr.isatty()
    return bool(progress)


class ModelStream(ABC):
    """Frames for phones that arrive in time order (a recogniser's or a TTS engine's).

    :meth:`push` takes the next phones (none overlapping the ones before) and returns
    ``(start_frame, frames)``: the rows over :attr:`channels` at :attr:`fps` that became
    computable, possibly none; :meth:`finish` returns the rest, up to the last phone's end.
    Frame t is given once the phones cover frame ``t + lookahead``.
    """

    def __init__(self, model: Estimator, language: str, fps: float) -> None:
        if not (np.isfinite(fps) and fps > 0):
            raise VispeechError(f"fps must be positive, got {fps}")
        self.model = model
        self.language = language
        self.fps = float(fps)
        self.channels = tuple(model.channels)
        self.lookahead = model.lookahead
        self.end = 0.0
        """Latest phone end so far, seconds."""
        self.emitted = 0
        """Frames given so far."""
        self.closed = False

    @abstractmethod
    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        """Add phones; the frames that became ready."""

    @abstractmethod
    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed."""

    def feed(self, phones: Iterable[Phone]) -> None:
        """Add phones, their frames to be taken with :meth:`collect`: :meth:`push` in two halves,
        so that the model work of several streams can be done together in between
        (:meth:`advance_together`). By default the work is done here."""
        start, rows = self.push(phones)
        fed = getattr(self, "_fed", None)
        self._fed = (start, rows) if fed is None or not len(fed[1]) else (fed[0], np.concatenate([fed[1], rows]))

    def collect(self) -> tuple[int, np.ndarray]:
        """The frames that became ready since the last :meth:`feed`."""
        fed, self._fed = getattr(self, "_fed", None), None
        return fed if fed is not None else self._empty()

    @classmethod
    def advance_together(cls, streams: Sequence[ModelStream]) -> None:
        """Do the model work that :meth:`feed` left in ``streams`` (all of this class), sharing
        model calls where the class can; by default there is none left."""

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self.closed = True

    def _empty(self) -> tuple[int, np.ndarray]:
        return self.emitted, np.zeros((0, len(self.channels)))


class WindowStream(ModelStream):
    """Any model streamed by re-predicting a bounded recent window.

    Each step predicts the phones from ``context`` seconds before the first frame not yet
    given up to the latest phone end, on a frame grid aligned with the stream's, and keeps the
    frames now ready (those ``lookahead`` frames before the phones' end).
    """

    def __init__(self, model: Estimator, language: str, fps: float, context: float = 0.5) -> None:
        super().__init__(model, language, fps)
        self.context_frames = round(context * self.fps)
        self._recent: list[Phone] = []
        self._grid = 1  # windows start on multiples of this many stream frames, a whole number of model frames
        if model.frame_rate is not None:
            ratio = rate_ratio(model.frame_rate, self.fps)
            if ratio is not None:
                self._grid = ratio.denominator
            self.lookahead = math.ceil((model.lookahead + 1) * self.fps / model.frame_rate)

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        new = list(phones)
        if self.closed:
            raise VispeechError("this phone stream has ended")
        if new:
            self._recent += new
            self.end = new[-1].end
        return self._emit(final=False)

    def finish(self) -> tuple[int, np.ndarray]:
        if self.closed:
            raise VispeechError("this phone stream has ended")
        out = self._emit(final=True)
        self.close()
        return out

    def _emit(self, final: bool) -> tuple[int, np.ndarray]:
        known = first_frame(self.end, self.fps)  # frames before the phones' end
        upto = known if final else known - self.lookahead
        if upto <= self.emitted or not self._recent:
            return self._empty()
        first_time = max(0, self.emitted - self.context_frames) / self.fps
        window = [p for p in self._recent if p.end > first_time] or self._recent[-1:]
        shift = first_frame(window[0].start, self.fps, after=False)
        shift -= shift % self._grid  # whole stream (and model) frames, so the grids agree
        local = PhoneSequence(window, self.language).shifted(-shift / self.fps).with_gaps_filled()
        values = self.model.predict(local, self.fps).values
        rows = values[np.clip(np.arange(self.emitted, upto) - shift, 0, len(values) - 1)]
        start, self.emitted = self.emitted, upto
        keep_after = max(0, self.emitted - self.context_frames) / self.fps
        self._recent = [p for p in self._recent if p.end > keep_after] or self._recent[-1:]
        return start, rows


class ResampledFrames:
    """Model frames (at ``model_fps``) as they are computed, given out at a stream's ``fps``
    interpolated as :meth:`vispeech.motion.track.Track.resample` does, so a stream's frames equal
    the offline prediction's; model frames no later stream frame needs are dropped."""

    def __init__(self, model_fps: float, fps: float) -> None:
        self.model_fps, self.fps = float(model_fps), float(fps)
        self.first = 0
        """Model frame index of the oldest frame kept."""
        self._frames: list[np.ndarray] = []

    def add(self, row: np.ndarray) -> None:
        """Append the next model frame."""
        self._frames.append(row)

    @property
    def computed(self) -> int:
        """Model frames computed so far."""
        return self.first + len(self._frames)

    def ready(self) -> int:
        """Stream frames whose interpolation the computed model frames cover."""
        if not self.computed:
            return 0
        return first_frame((self.computed - 1) / self.model_fps, self.fps, after=False) + 1

    def give(self, emitted: int, upto: int) -> np.ndarray:
        """Stream frames ``emitted .. upto - 1`` (frames past the last model frame hold its values);
        needs at least one model frame."""
        times = np.arange(emitted, upto) / self.fps
        source = (self.first + np.arange(len(self._frames))) / self.model_fps
        values = np.stack(self._frames)
        rows = np.column_stack([np.interp(times, source, values[:, j]) for j in range(values.shape[1])])
        drop = min(max(0, int(np.floor(upto * self.model_fps / self.fps)) - 1 - self.first), len(self._frames) - 1)
        del self._frames[:drop]
        self.first += drop
        return rows


def rate_ratio(model_fps: float, fps: float) -> Fraction | None:
    """``model_fps / fps`` as a simple fraction (denominator at most 1000), or ``None`` when it is none:
    every ``denominator`` frames at ``fps`` are a whole number (``numerator``) of model frames."""
    ratio = Fraction(model_fps / fps).limit_denominator(1000)
    return ratio if abs(float(ratio) - model_fps / fps) < 1e-9 else None
