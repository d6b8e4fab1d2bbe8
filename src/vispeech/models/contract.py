"""The model contract: what every control model is and does, whatever its family or input.

A control model is an estimator in scikit-learn's sense, generic in what it animates
(:data:`InputT`: a :class:`~vispeech.alignment.phones.PhoneSequence` or an
:class:`~vispeech.frontends.audio.AudioClip`, named at run time by :attr:`Estimator.input_kind`):

- the constructor stores *hyper-parameters* only (the training budget included), given by
  keyword over the family's :attr:`Estimator.defaults`; :meth:`~Estimator.get_params` returns
  them and never changes after :meth:`~Estimator.fit`; :meth:`~Estimator.set_params` changes
  them, checked as the constructor checks them; :func:`clone` is a new, unfitted model with
  the same ones;
- :meth:`~Estimator.fit` ``(corpus, *, progress=None, checkpoint_dir=None, resume_from=None,
  num_threads=None, warm_start=False) -> self`` learns from a corpus (an object with ``split("train")`` and
  ``split("validation")``, or any iterable of utterances with ``.phones`` and ``.track``, all
  of them used for training: :mod:`vispeech.models.fitting`); its keywords are settings of the
  run, never stored; what it learns lives in attributes whose names end in ``_``; data-free
  families (rules with authored parameters) are ready without it;
- :meth:`~Estimator.predict` ``(inputs, fps) -> Track`` animates one utterance's inputs, and
  :meth:`~Estimator.predict_with_closures` also gives the bilabials an audio model hears;
  :attr:`~Estimator.is_fitted` says whether they can run;
- :attr:`~Estimator.lookahead` is how many frames of input after frame t a stream needs
  before it gives frame t, and :meth:`~Estimator.stream` predicts incrementally as inputs
  arrive (:class:`~vispeech.models.streams.ModelStream`, the engine in :mod:`vispeech.models.streams`);
- :meth:`~Estimator.save` and :meth:`Estimator.load` are the same for every family: a folder
  with ``config.json`` and, when there are arrays, ``weights.safetensors``, no pickle
  (:mod:`vispeech.models.persistence`).

A model is known by one read-only :attr:`~Estimator.name`: its family's for a new one, the
shipped name (``grid-tdnn``) for a shipped one, and the name it was saved under otherwise.
"""

from __future__ import annotations

import copy
import os
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.limits import check_fps, check_utterance
from vispeech.models.fitting import FitRun
from vispeech.models.persistence import FOLDER_NAMES, model_from_config, read_config, write_model
from vispeech.models.streams import ModelStream, WindowStream
from vispeech.motion.track import Track

if TYPE_CHECKING:
    from vispeech.alignment.phones import PhoneSequence
    from vispeech.frontends.audio import AudioClip

InputT = TypeVar("InputT", bound="PhoneSequence | AudioClip")
"""What a family animates: :class:`~vispeech.alignment.phones.PhoneSequence` or
:class:`~vispeech.frontends.audio.AudioClip` (its :attr:`Estimator.input_kind` says which at run time)."""
_Self = TypeVar("_Self", bound="Estimator[Any]")


class Estimator(ABC, Generic[InputT]):
    """Base of every control model, generic in what it animates (:data:`InputT`); see the
    module docstring for the contract."""

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
        self._check_names(params)
        self._params = {key: _plain(params.get(key, value)) for key, value in self.defaults.items()}
        self._name = self.family
        self._check_values()

    def _check_names(self, params: Mapping[str, Any]) -> None:
        unknown = sorted(set(params) - set(self.defaults))
        if unknown:
            known = ", ".join(sorted(self.defaults)) or "none"
            raise VispeechError(f"model {self.family} has no parameter {unknown[0]!r} (it has: {known})")

    def _check_params(self) -> None:
        """Raise :class:`VispeechError` on a bad hyper-parameter value (and forget whatever was
        computed from the values before: it runs again on :meth:`set_params`)."""

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """A copy of the hyper-parameters (``deep``: scikit-learn's argument; no model holds another)."""
        return copy.deepcopy(self._params)

    def __sklearn_clone__(self: _Self) -> _Self:
        """What ``sklearn.base.clone`` gives: :func:`clone` (its check that the constructor keeps
        each parameter object as given does not hold for copies)."""
        return clone(self)

    def set_params(self: _Self, **params: Any) -> _Self:
        """Change these hyper-parameters, checked as the constructor checks them; returns ``self``.

        What the model learned stays (a warm start fits on from it); on a bad name or value the
        model is left as it was and :class:`VispeechError` is raised.
        """
        self._check_names(params)
        before = self._params
        self._params = {**before, **{key: _plain(value) for key, value in params.items()}}
        try:
            self._check_values()
        except VispeechError:
            self._params = before
            self._check_params()
            raise
        return self

    def _check_values(self) -> None:
        """:meth:`_check_params`, with a value of the wrong type (a word where a number goes, a
        number where a list goes) told as a :class:`VispeechError` naming it, not a crash of
        the checks' comparisons."""
        try:
            self._check_params()
        except VispeechError:
            raise
        except (TypeError, ValueError) as error:
            odd = [key for key, value in self._params.items() if not _same_kind(value, self.defaults[key])]
            if not odd:
                raise VispeechError(f"model {self.family}: a hyper-parameter cannot be used ({error})") from None
            raise VispeechError(
                f"model {self.family}: "
                + "; ".join(f"{key} must be like {self.defaults[key]!r}, got {self._params[key]!r}" for key in odd)
            ) from None

    @property
    def name(self) -> str:
        """What the model is known by: its family's name when new, else the name it was saved
        under (:meth:`save`) or loaded with (a shipped model's, ``grid-tdnn``)."""
        return self._name

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

    def fit(
        self: _Self,
        corpus,
        *,
        progress: bool | None = None,
        checkpoint_dir: str | os.PathLike | None = None,
        resume_from: str | os.PathLike | None = None,
        num_threads: int | None = None,
        warm_start: bool = False,
    ) -> _Self:
        """Learn from ``corpus``; returns ``self``. The keywords are settings of this run, not
        hyper-parameters: ``progress``, bars and lines on stderr (``None``: when stderr is a
        terminal); ``checkpoint_dir``, a folder to keep the run in after every epoch;
        ``resume_from``, a folder holding a run of this model to go on from (a checkpoint of an
        interrupted fit, or a saved model); ``num_threads``, the most threads it may use
        (``None``: the library's default); ``warm_start``, start from what the model has learned
        instead of afresh. A family fitted in one go refuses all but ``progress`` and
        ``num_threads`` (:meth:`~vispeech.models.fitting.FitRun.in_one_go`)."""
        return self._fit(corpus, FitRun.of(progress, checkpoint_dir, resume_from, num_threads, warm_start))

    @abstractmethod
    def _fit(self: _Self, corpus, run: FitRun) -> _Self:
        """What :meth:`fit` does in each family: learn from ``corpus`` with the settings of ``run``."""

    @abstractmethod
    def predict(self, inputs: InputT, fps: float) -> Track:
        """A track of ``inputs.n_frames(fps)`` frames from time 0 over :attr:`channels`."""

    def predict_many(self, inputs: Sequence[InputT], fps: float) -> list[Track]:
        """:meth:`predict` of each of ``inputs``, the same tracks; a family that can runs them
        together (a recurrent network steps all the utterances at once)."""
        return [self.predict(x, fps) for x in inputs]

    def predict_with_closures(self, inputs: InputT, fps: float) -> tuple[Track, PhoneSequence | None]:
        """:meth:`predict`'s track and the bilabials the model hears in audio, as phones that
        post-processing may shut the lips on; ``None`` (the default) for a model that hears none."""
        return self.predict(inputs, fps), None

    def saved_parts(self) -> list[tuple[Estimator, Path | None]]:
        """The saved models this one animates with, each with its folder (an ensemble's members):
        their versions are part of its own (:func:`~vispeech.models.registry.model_version`).
        None for a model whole in itself (the default)."""
        return []

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

    def check_inputs(self, inputs: InputT, fps: float) -> None:
        """Raise :class:`VispeechError` unless ``inputs`` are what the model animates
        (:attr:`input_kind`: a valid :class:`~vispeech.alignment.phones.PhoneSequence` or an
        :class:`~vispeech.frontends.audio.AudioClip`) within the library's limits, at a frame rate
        ``fps`` within them (:mod:`vispeech.limits`): called before any work, by every way to predict."""
        from vispeech.alignment.phones import PhoneSequence
        from vispeech.frontends.audio import AudioClip

        check_fps(fps)
        if self.input_kind == "audio":
            if not isinstance(inputs, AudioClip):
                raise VispeechError(f"{self.name} animates audio (an AudioClip), not {type(inputs).__name__}")
            check_utterance(inputs.duration, 0)
            return
        if not isinstance(inputs, PhoneSequence):
            raise VispeechError(f"{self.name} animates phones (a PhoneSequence), not {type(inputs).__name__}")
        inputs.validate()
        check_utterance(inputs.duration, len(inputs))

    def check_fitted(self) -> None:
        """Raise :class:`VispeechError` unless :attr:`is_fitted`."""
        if not self.is_fitted:
            raise VispeechError(
                f"model {self.name} is not trained: fit it on a corpus (vispeech train) or load a trained one"
            )

    def save(self, path: str | os.PathLike, *, name: str | None = None) -> Path:
        """Write the model into folder ``path`` as a whole (:mod:`vispeech.models.persistence`)
        under ``name`` (``None``: its :attr:`name`), which the model is known by from then on;
        returns the folder.

        The new folder replaces ``path`` in one step (:func:`vispeech.files.atomic_output_dir`):
        an existing folder is replaced only when it holds nothing but
        :data:`~vispeech.models.persistence.FOLDER_NAMES`, otherwise :class:`VispeechError`.
        """
        name = self.name if name is None else name
        with atomic_output_dir(path, replaces=FOLDER_NAMES) as staging:
            write_model(self, staging, name)
        self._name = name
        return Path(path)

    @classmethod
    def load(cls: type[_Self], path: str | os.PathLike) -> _Self:
        """Read a folder written by :meth:`save` into a model of this family (or a subclass's).

        Raises :class:`VispeechError` if the folder is missing or corrupt or holds another family.
        """
        folder = Path(path)
        config = read_config(folder)
        if config["family"] != cls.family:
            raise VispeechError(f"{folder} holds a {config['family']} model, not a {cls.family} model")
        return model_from_config(cls, folder, config)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} ({self.family}{'' if self.is_fitted else ', not fitted'})>"


def clone(model: _Self) -> _Self:
    """A new, unfitted model of ``model``'s family with the same hyper-parameters (scikit-learn's
    ``clone``): nothing learned, known by its family's name."""
    return type(model)(**model.get_params())


def _same_kind(value: Any, default: Any) -> bool:
    """Whether ``value`` is of the kind of ``default`` (a number, a flag, a word, a list or a
    mapping; anything where the default is ``None``)."""
    if default is None:
        return True
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, int | float):
        return isinstance(value, int | float)
    return isinstance(value, type(default))


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
