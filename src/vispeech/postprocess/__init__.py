"""Post-processing of predicted tracks: jaw shift, consonant overlays, closures, ceilings, rest.

:func:`postprocess` runs, in order: the thesis's jawOpen range shift; the optional upper-lip
overlay; the consonant overlays (bilabial closure, labiodental contact); the opening of every
vowel, however short; the tongue channels from the phones' features
(:mod:`~vispeech.postprocess.tongue`); confinement of the jaw's peaks to vowels; the soft
ceilings; ``mouthClose ≤ jawOpen``; clipping to [0, 1]; the mouth at rest in silence
(:mod:`~vispeech.postprocess.rest`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vispeech.alignment.phones import PhoneSequence, first_frame
from vispeech.errors import VispeechError
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import is_vowel
from vispeech.postprocess.overlays import (
    VOWEL_OPENING,
    anchor_frames,
    consonant_overlays,
    open_vowels,
    upper_lip_overlay,
)
from vispeech.postprocess.rest import rest_in_silence, speech_intervals
from vispeech.postprocess.shaping import SoftCeiling, confine_peaks, shift_range
from vispeech.postprocess.tongue import tongue_channels
from vispeech.targets.presets import PRESETS

__all__ = [
    "AUTO",
    "DEFAULT_CEILINGS",
    "NONE",
    "PostprocessConfig",
    "Postprocessing",
    "SoftCeiling",
    "check_postprocessing",
    "postprocess",
    "postprocessing_config",
]

DEFAULT_CEILINGS: Mapping[str, SoftCeiling] = {
    "jawOpen": SoftCeiling(threshold=0.45, maximum=0.55),
    "mouthPucker": SoftCeiling(threshold=0.6, maximum=0.7),
}
"""Absolute soft ceilings (the thesis's jawOpen and mouthPucker ceilings, without a ground truth)."""


@dataclass
class PostprocessConfig:
    """What :func:`postprocess` does; every step is on by default except the upper-lip lift.

    ``jaw_shift``: the thesis's a (0 = off). ``overlays``: consonant overlays, with
    ``fade_in`` (phone lengths) and ``fade_out`` (a per-phone spec of phone lengths, ``None``
    for the default); ``overlay_features`` limits them to consonants with one of these
    articulatory features (``None``: all), and ``keep_jaw`` makes them leave jawOpen alone and
    reach each viseme's lip opening through mouthClose (for models that learned the jaw from
    recordings). ``upper_lip``: lift of mouthUpperUp during speech (0 = off).
    ``vowel_opening``: the share of the utterance's open-vowel lip opening every vowel reaches
    on its anchor frame (:func:`~vispeech.postprocess.overlays.open_vowels`; 0 = off).
    ``tongue``: add the tongue channels (:data:`~vispeech.motion.arkit.TONGUE_CHANNELS`).
    ``jaw_peaks_in_vowels``: lower jawOpen between vowels so its peaks fall in vowels.
    ``ceilings``: soft ceilings per channel. ``rest``: ease the jaw, lips and tongue to rest
    away from speech (:mod:`~vispeech.postprocess.rest`). ``close_within_jaw``: clamp mouthClose
    to jawOpen (ARKit's lips interpenetrate beyond that).
    """

    jaw_shift: float = 0.07
    overlays: bool = True
    fade_in: float = 1.5
    fade_out: Mapping | None = None
    overlay_features: Sequence[str] | None = None
    keep_jaw: bool = False
    upper_lip: float = 0.0
    vowel_opening: float = VOWEL_OPENING
    tongue: bool = True
    jaw_peaks_in_vowels: bool = True
    ceilings: Mapping[str, SoftCeiling] = field(default_factory=lambda: dict(DEFAULT_CEILINGS))
    rest: bool = True
    close_within_jaw: bool = True

    @classmethod
    def from_preset(cls, name: str) -> PostprocessConfig:
        """The settings of a named preset (:data:`vispeech.targets.presets.PRESETS`)."""
        if name not in PRESETS:
            raise VispeechError(f"unknown post-processing preset {name!r} (use {', '.join(PRESETS)})")
        return cls(**PRESETS[name])

    def __post_init__(self) -> None:
        if not (0.0 <= self.jaw_shift < 1.0 and self.fade_in >= 0.0 and 0.0 <= self.upper_lip <= 1.0):
            raise VispeechError("postprocess needs 0 <= jaw_shift < 1, fade_in >= 0 and 0 <= upper_lip <= 1")
        if not 0.0 <= self.vowel_opening <= 1.0:
            raise VispeechError("postprocess needs 0 <= vowel_opening <= 1")


AUTO = "auto"
"""The post-processing that suits the model: the preset it recommends
(:attr:`~vispeech.models.contract.Estimator.postprocessing`), or what the pipeline picks for its
input (:func:`vispeech.pipeline.animate_audio`)."""
NONE = "none"
"""No post-processing: the model's own output."""

Postprocessing = PostprocessConfig | str
"""How a track is post-processed, one parameter everywhere (``postprocessing``, the CLI's
``--postprocessing``, a batch line's ``postprocessing``): a configuration, the name of a preset
(:data:`~vispeech.targets.presets.PRESETS`), :data:`AUTO` or :data:`NONE`."""


def check_postprocessing(postprocessing: Postprocessing) -> Postprocessing:
    """``postprocessing`` if it is a configuration or a known name; :class:`VispeechError` otherwise."""
    if isinstance(postprocessing, PostprocessConfig) or postprocessing in (AUTO, NONE, *PRESETS):
        return postprocessing
    raise VispeechError(
        f"unknown post-processing {str(postprocessing)[:40]!r} (use {AUTO}, {NONE} or a preset: {', '.join(PRESETS)})"
    )


def postprocessing_config(postprocessing: Postprocessing, recommended: str) -> PostprocessConfig | None:
    """The configuration ``postprocessing`` names (``None`` for :data:`NONE`), with ``recommended``
    the preset :data:`AUTO` stands for."""
    checked = check_postprocessing(postprocessing)
    if isinstance(checked, PostprocessConfig):
        return checked
    if checked == NONE:
        return None
    return PostprocessConfig.from_preset(recommended if checked == AUTO else checked)


def postprocess(
    track: Track,
    phones: PhoneSequence | None,
    config: PostprocessConfig | None = None,
    *,
    speech: Iterable[tuple[float, float]] | None = None,
) -> Track:
    """The post-processed copy of ``track``, a track for ``phones`` at its own fps.

    ``phones`` may be ``None`` (audio animated without a transcript) when ``config`` has no
    step keyed on phones (the ``audio`` preset). ``speech``: for a track of audio, the spans
    (start, end seconds) in which its loudness shows speech
    (:func:`~vispeech.frontends.activity.speech_span`; ``[]``: none), away from which the mouth
    rests; without them it rests away from the phones that are not silence.

    The result keeps the track's channels and adds those the overlays set; all values lie
    in [0, 1]. With overlays on, every /p b m/ reaches lip closure
    (:func:`vispeech.motion.arkit.lip_aperture` ≤ ``LIP_CLOSED``) on its anchor frame.
    """
    config = config or PostprocessConfig()
    if phones is None:
        if config.overlays or config.upper_lip or config.jaw_peaks_in_vowels or config.vowel_opening or config.tongue:
            raise VispeechError(
                "post-processing with overlays, upper-lip lift, vowel opening, tongue or jaw confinement needs phones"
            )
    else:
        phones.validate()
    out = track.copy()
    if config.jaw_shift > 0 and "jawOpen" in out.channels:
        out.values[:, out.index("jawOpen")] = shift_range(out["jawOpen"], config.jaw_shift)
    if config.upper_lip > 0:
        assert phones is not None  # refused above: these steps need phones
        out = upper_lip_overlay(out, phones, config.upper_lip)
    if config.overlays:
        assert phones is not None
        out = consonant_overlays(out, phones, config.fade_in, config.fade_out, config.overlay_features, config.keep_jaw)
    if config.vowel_opening > 0:
        assert phones is not None
        out = open_vowels(out, phones, config.vowel_opening)
    if config.tongue:
        assert phones is not None
        out = tongue_channels(out, phones)
    if config.jaw_peaks_in_vowels and "jawOpen" in out.channels:
        assert phones is not None
        jaw = out.index("jawOpen")
        out.values[:, jaw] = confine_peaks(out.values[:, jaw], _vowel_frames(out, phones))
    for channel, ceiling in config.ceilings.items():
        if channel in out.channels:
            out.values[:, out.index(channel)] = ceiling(out[channel])
    if config.close_within_jaw and {"jawOpen", "mouthClose"} <= set(out.channels):
        close = out.index("mouthClose")
        out.values[:, close] = np.minimum(out.values[:, close], out["jawOpen"])
    np.clip(out.values, 0.0, 1.0, out=out.values)
    if config.rest:
        where = phones if speech is None else speech
        if where is None:
            raise VispeechError("post-processing with the mouth at rest in silence needs phones or the speech spans")
        out = rest_in_silence(out, speech_intervals(where))
    return out


def _vowel_frames(track: Track, phones: PhoneSequence) -> np.ndarray:
    """Frames inside a vowel, plus the nearest frame of each vowel shorter than a frame."""
    vowels = [p for p in phones if is_vowel(p.symbol, phones.language)]
    starts = np.array([p.start for p in vowels]) - track.start_time
    ends = np.array([p.end for p in vowels]) - track.start_time
    n = track.n_frames
    first = np.clip(first_frame(starts, track.fps), 0, n)
    stop = np.clip(first_frame(ends, track.fps), first, n)
    inside = np.cumsum(np.bincount(first, minlength=n + 1) - np.bincount(stop, minlength=n + 1))[:n] > 0
    inside[anchor_frames(starts, ends, track.fps, n)] = True
    return inside
