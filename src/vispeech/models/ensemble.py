"""An ensemble of audio networks: the weighted mean of what each hears (scikit-learn's ``VotingRegressor``).

Networks on different front ends err differently on a voice none of them heard, so their mean
carries further than any one: ``grid-audio-whisper-ensemble``, the mean of ``grid-audio-whisper``
(Whisper tiny.en), ``grid-audio-whisper-base`` (Whisper base) and ``grid-audio-cnn`` (log-mel),
agrees with the phone model on espeak-ng's voices at a mean pooled jawOpen r of 0.58 against
0.46 and 0.52 for the Whisper networks alone, and scores 0.888 on grid_s1's validation split
against 0.880 and 0.884 (docs/audio.md).

An :class:`AudioEnsemble` learns nothing itself: its ``members`` are trained audio networks named
as :func:`~vispeech.models.registry.load_model` takes them (shipped names, or saved folders,
best given as absolute paths since a saved ensemble keeps them as given), loaded when it is
made. Its frames are the ``weights``-weighted mean of the members' on the first member's
channels, which every member must have, at the members' motion range: members that disagree
(on a voice none of them heard) cancel each other's movement, so their mean moves 20 to 30 %
less than they do (the jaw of ``grid-audio-whisper-ensemble`` on espeak-ng's voices and on TV
and web speech; 1 % on its training speaker), and each channel's deviation from its mean over
the clip is scaled so that its standard deviation is the weighted mean of the members' (an
affine map per clip, which leaves the channel's correlation with anything unchanged but for
the clipping to [0, 1]). With ``closure_threshold`` > 0 it hears bilabials in the weighted mean
of the CTC posteriors of the members that hear them alone (their own ``closure_threshold`` > 0:
a head not trusted alone, as ``grid-audio-cnn``'s, is left out;
:func:`~vispeech.models.networks.phone_head.heard_bilabials`), which needs at least one such
member and all of them with heads over the same phones at the same frame rate. It animates
whole recordings: it does not stream.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.models.contract import Estimator
from vispeech.models.fitting import FitRun
from vispeech.models.networks.audio import AudioNetwork
from vispeech.models.networks.phone_head import check_closure_params, heard_bilabials
from vispeech.models.registry import load_model, saved_folder
from vispeech.models.streams import ModelStream
from vispeech.motion.track import Track


class AudioEnsemble(Estimator[AudioClip]):
    """The weighted mean of trained audio networks' frames (and of their CTC heads' posteriors).

    Parameters: ``members``, two or more audio networks by name or folder (none: a new ensemble,
    not ready to predict); ``weights``, one positive number per member (``None``: equal),
    normalised to sum 1; ``closure_threshold`` and ``closure_length``, as an audio network's, on
    the mean posteriors of the members that hear bilabials themselves (0: hears none). Learned:
    ``members_``, the loaded networks.
    """

    family = "audio-ensemble"
    input_kind = "audio"
    trainable = False
    defaults = {"members": [], "weights": None, "closure_threshold": 0.0, "closure_length": 0.08}

    members_: list[AudioNetwork]

    def _check_params(self) -> None:
        p = self._params
        members, weights = p["members"], p["weights"]
        if not isinstance(members, list) or len(members) == 1 or not all(isinstance(m, str) for m in members):
            raise VispeechError("an audio ensemble's members must be two or more audio model names or folders")
        if weights is not None and (
            not isinstance(weights, list)
            or len(weights) != len(members)
            or not all(isinstance(w, int | float) and not isinstance(w, bool) and w > 0 for w in weights)
        ):
            raise VispeechError(
                f"an audio ensemble's weights must be {len(members)} positive numbers, one a member, got {weights!r}"
            )
        check_closure_params(p["closure_threshold"], p["closure_length"])
        if not members:  # a new ensemble has none yet: not ready to predict
            self.__dict__.pop("members_", None)
            return
        if getattr(self, "_loaded", None) != members:
            loaded: list[AudioNetwork] = []
            for name in members:
                model = load_model(name)
                if not isinstance(model, AudioNetwork):
                    raise VispeechError(
                        f"ensemble member {name} is a {model.family} model: an audio ensemble takes audio networks"
                    )
                loaded.append(model)
                missing = sorted(set(loaded[0].channels) - set(model.channels))
                if missing:
                    raise VispeechError(f"ensemble member {name} lacks the channels {', '.join(missing[:3])}")
            self.members_, self._loaded = loaded, list(members)
        if p["closure_threshold"]:
            heads = {(tuple(m.phones_), m.phone_language_, m.fps_) for m in self._hearing()}
            if len(heads) != 1 or not next(iter(heads))[0]:
                raise VispeechError(
                    "an audio ensemble hears bilabials (closure_threshold > 0) only when some members do "
                    "(their own closure_threshold > 0), all with CTC heads over the same phones at the same frame rate"
                )

    def _members(self) -> list[AudioNetwork]:
        """The loaded members (none before any are named)."""
        return self.members_ if self.is_fitted else []

    def _hearing(self) -> list[AudioNetwork]:
        """The members that hear bilabials alone, whose posteriors the ensemble's closures come from."""
        return [m for m in self.members_ if m.get_params()["closure_threshold"]]

    @property
    def channels(self) -> tuple[str, ...]:
        members = self._members()
        return members[0].channels if members else ()

    @property
    def weights(self) -> np.ndarray:
        """The members' weights, summing to 1."""
        given = self._params["weights"] or [1.0] * len(self.members_)
        return np.asarray(given, dtype=float) / sum(given)

    @property
    def frame_rate(self) -> float | None:
        rates = {m.frame_rate for m in self._members()}
        return rates.pop() if len(rates) == 1 else None

    @property
    def lookahead(self) -> int:
        return max((m.lookahead for m in self._members()), default=0)

    @property
    def postprocessing(self) -> str:
        return "audio"

    def check_fitted(self) -> None:
        if not self.is_fitted:
            raise VispeechError(
                f"audio ensemble {self.name} has no members: name two or more trained audio networks in members"
            )

    def _fit(self, corpus, run: FitRun) -> AudioEnsemble:
        raise VispeechError(
            "an audio ensemble learns nothing itself: train its members (vispeech train) and name them in members"
        )

    def predict(self, clip: AudioClip, fps: float) -> Track:
        """A track of ``clip.n_frames(fps)`` frames: the weighted mean of the members' tracks at
        their motion range (see the module docstring)."""
        return self.predict_with_closures(clip, fps)[0]

    def predict_with_closures(self, clip: AudioClip, fps: float) -> tuple[Track, PhoneSequence | None]:
        """:meth:`predict`'s track and the bilabials heard in the members' mean posteriors
        (``None`` at ``closure_threshold`` 0)."""
        self.check_fitted()
        self.check_inputs(clip, fps)
        values: Any = 0.0
        spread: Any = 0.0
        posteriors: Any = 0.0
        hearing = self._hearing()
        heard_weight = sum(w for w, m in zip(self.weights, self.members_, strict=True) if m in hearing)
        for weight, member in zip(self.weights, self.members_, strict=True):
            track, heard = member.predict_with_posteriors(clip, fps)
            frames = track.select(self.channels).values
            values = values + weight * frames
            spread = spread + weight * frames.std(axis=0)
            if heard is not None and member in hearing:
                posteriors = posteriors + weight / heard_weight * heard
        track = Track(_with_spread(values, spread), self.channels, fps)
        p = self._params
        if not p["closure_threshold"]:
            return track, None
        head = hearing[0]
        assert head.phone_language_ is not None  # _check_params: every member has the same head
        return track, heard_bilabials(
            posteriors, head.phones_, head.phone_language_, head.fps_, p["closure_threshold"], p["closure_length"]
        )

    def saved_parts(self) -> list[tuple[Estimator, Path | None]]:
        """The members, each with the folder it was loaded from: a member retrained in its folder
        changes the ensemble's version (what a batch and the server's cache key its outputs by)."""
        return [(member, saved_folder(name)) for member, name in zip(self._members(), self._params["members"])]

    def stream(self, language: str, fps: float) -> ModelStream:
        raise VispeechError(
            f"{self.name} animates whole recordings and does not stream: live audio takes a streaming "
            "audio network (grid-audio-cnn)"
        )

    def _learned_state(self) -> None:
        return None  # the members are saved under their own names

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        raise ValueError("an audio ensemble keeps no learned state of its own")


def _with_spread(values: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """``values`` ``(frames, channels)`` moved about their mean over the frames so that each
    channel's standard deviation is ``spread`` (where it moves at all), within [0, 1]."""
    mean = values.mean(axis=0)
    own = values.std(axis=0)
    scale = np.divide(spread, own, out=np.ones_like(own), where=own > 1e-9)
    return np.clip(mean + (values - mean) * scale, 0.0, 1.0)
