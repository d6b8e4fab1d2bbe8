"""Öhman's (1967) look-ahead model, extended to any phone sequence as in Beskow (2004).

A vowel track v(t) joins the targets of successive vowels (and silences, which act as the
neutral mouth) with smoothstep cubics 3s² − 2s³ between their centres, held before the
first and after the last. Each consonant i adds a gesture toward its target c_i:

    z(t) = v(t) + Σ_i w_i · k_i(t) · (c_i − v(t))

with k_i rising from 0 at the previous segment's centre to 1 at τ_i and falling to 0 at the
next segment's centre (smoothstep halves, zero slope at all three points; the sequence's
start and end stand in for missing neighbours). The coarticulation factor w ∈ [0, 1] is per
consonant and channel: 1 reaches the consonant's target, 0 leaves the vowel track alone.

:meth:`Ohman.fit` estimates the targets and the factors from recorded tracks (see
:mod:`vispeech.models.rules.dominance_fit`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.fitting import FitRun
from vispeech.models.rules.dominance_fit import FitData, PhoneTying, Recording, fit_channels, scatter_jacobian
from vispeech.models.rules.phone_targets import PhoneTargetModel, family_defaults
from vispeech.models.rules.segments import Segments
from vispeech.motion.easing import smoothstep
from vispeech.motion.track import Track
from vispeech.phonetics.features import phone_rows
from vispeech.phonetics.inventory import LANGUAGES, SILENCE
from vispeech.targets.tables import resolve_spec


class Ohman(PhoneTargetModel):
    """Vowel track plus consonant gestures. Hyper-parameters: ``w_c`` (per-phone spec of the
    coarticulation factor, values in [0, 1]), ``targets`` (per-phone target overrides) and,
    for :meth:`fit`, ``channels``, ``max_iterations`` and ``patience`` as for
    :class:`~vispeech.models.rules.cohen_massaro.CohenMassaro`."""

    family = "ohman"
    defaults = {**family_defaults("ohman"), "channels": None, "max_iterations": 100, "patience": 3}
    trainable = True
    table_names = ("targets", "w_c")

    def _check_params(self) -> None:
        super()._check_params()
        self._check_fit_params()
        if any(((w < 0) | (w > 1)).any() for w in (self._authored(lang)["w_c"] for lang in LANGUAGES)):
            raise VispeechError("ohman w_c values must lie in [0, 1]")

    def _authored_tables(self, language: str) -> dict[str, np.ndarray]:
        return {**super()._authored_tables(language), "w_c": resolve_spec(self._params["w_c"], language, self.channels)}

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        blend = _Blend.of(seg)
        tables = self.tables(seg.language)
        targets, w = tables["targets"], tables["w_c"]
        first = targets[blend.anchors[:, 0]]
        vowel_track = first + blend.shift[:, None] * (targets[blend.anchors[:, 1]] - first)
        out = vowel_track.copy()
        for side in (0, 1):
            k = blend.consonants[:, side]
            gain = blend.strength[:, side, None] * w[k]
            out += gain * (targets[k] - vowel_track)
        return self._track(out, fps)

    def _fit(self, corpus, run: FitRun) -> Ohman:
        """Estimate every phone symbol's target and every consonant's w_c per channel by least
        squares; returns ``self``. Splits, channels and learned attributes as for
        :meth:`vispeech.models.rules.cohen_massaro.CohenMassaro.fit`."""
        run.in_one_go(self.family)
        p = self._params
        data = FitData.gather(self, corpus, p["channels"])
        tying = PhoneTying.of(data.language, data.train)
        factors = PhoneTying.of(data.language, data.train, rows=phone_rows(data.language).mask("consonant"))
        train = _Design(data.train, tying, factors)
        held = _Design(data.validation, tying, factors) if any(len(r.values) for r in data.validation) else None
        n, n_w = len(tying), len(factors)
        columns = [self.channels.index(c) for c in data.channels]
        authored = self._authored(data.language)
        targets, w = authored["targets"], authored["w_c"]
        means = tying.frame_means(data.train, targets[tying.first_rows][:, columns])
        lower, upper = np.zeros(n + n_w), np.ones(n + n_w)

        def start(j: int, m: int) -> tuple[tuple, np.ndarray]:
            return (targets[:, m], w[:, m]), np.concatenate([means[:, j], w[factors.first_rows, m]])

        fitted = fit_channels(self, data, start, lower, upper, train, held, run.progress)
        learned = {name: values.copy() for name, values in authored.items()}
        for channel, m in zip(data.channels, columns):
            learned["targets"][:, m] = tying.expand(targets[:, m], fitted[channel][:n])
            learned["w_c"][:, m] = factors.expand(w[:, m], fitted[channel][n:])
        self.tables_ = {data.language: learned}
        return self


@dataclass(frozen=True)
class _Blend:
    """Per frame time of some segments: the vowel track runs from the target of phone row
    ``anchors[:, 0]`` toward that of ``anchors[:, 1]`` by ``shift``; the consonants on the
    falling (column 0) and rising (column 1) side of the frame pull with gesture ``strength``
    k (0 where there is none)."""

    anchors: np.ndarray
    shift: np.ndarray
    consonants: np.ndarray
    strength: np.ndarray

    @classmethod
    def of(cls, seg: Segments) -> _Blend:
        t = seg.times
        anchor = seg.vowel | seg.silence
        if anchor.sum() >= 2:
            centres, rows = seg.centres[anchor], seg.rows[anchor]
            m = np.clip(np.searchsorted(centres, t, side="right") - 1, 0, len(centres) - 2)
            shift = smoothstep((t - centres[m]) / (centres[m + 1] - centres[m]))
            anchors = np.column_stack([rows[m], rows[m + 1]])
        else:  # one anchor holds its target; none holds the silence target
            row = seg.rows[anchor][0] if anchor.any() else phone_rows(seg.language).keys[SILENCE, False]
            anchors, shift = np.full((len(t), 2), row), np.zeros(len(t))
        n = len(seg.rows)
        knots = np.concatenate(([seg.starts[0]], seg.centres, [seg.ends[-1]]))
        j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, n)
        width = knots[j + 1] - knots[j]
        rise = smoothstep(np.divide(t - knots[j], width, out=np.ones_like(t), where=width > 0))
        consonants, strength = [], []
        for i, k in ((j - 1, 1.0 - rise), (j, rise)):  # falling side of segment j-1, rising side of j
            active = (i >= 0) & (i < n)
            i = np.clip(i, 0, n - 1)
            active &= ~anchor[i]
            consonants.append(seg.rows[i])
            strength.append(np.where(active, k, 0.0))
        return cls(anchors, shift, np.column_stack(consonants), np.column_stack(strength))


class _Design:
    """The frames of some recordings laid out for one channel's fit: per frame the blend
    (:class:`_Blend`) and the Jacobian columns of the targets and factors it involves."""

    def __init__(self, recordings: list[Recording], tying: PhoneTying, factors: PhoneTying):
        blends = [_Blend.of(r.segments) for r in recordings]
        names = ("anchors", "shift", "consonants", "strength")
        self.anchors, self.shift, self.consonants, self.strength = (
            np.concatenate([getattr(b, name) for b in blends]) for name in names
        )
        self.values = np.concatenate([r.values for r in recordings])
        self.tying, self.factors = tying, factors
        n = len(tying)
        self.n_params = n + len(factors)
        self.columns = (
            tying.columns(self.anchors),
            tying.columns(self.consonants),
            np.where(self.strength > 0, factors.columns(self.consonants, offset=n), -1),
        )

    def residuals(
        self, base: tuple[np.ndarray, np.ndarray], channel: int, x: np.ndarray, jacobian: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """z − y on these frames for parameters ``x`` (targets of the fitted symbols, then w_c
        of the fitted consonants) over the per-row tables ``base`` (targets, w_c), and ∂z/∂x."""
        n = len(self.tying)
        targets = self.tying.expand(base[0], x[:n])
        w = self.factors.expand(base[1], x[n:])
        ends = targets[self.anchors]
        vowel_track = ends[:, 0] + self.shift * (ends[:, 1] - ends[:, 0])
        pulled = targets[self.consonants]
        gain = self.strength * w[self.consonants]
        z = vowel_track + np.einsum("fs,fs->f", gain, pulled - vowel_track[:, None])
        r = z - self.values[:, channel]
        if not jacobian:
            return r, None
        rest = 1.0 - gain.sum(axis=1)  # ∂z/∂v
        along = np.column_stack([(1.0 - self.shift) * rest, self.shift * rest])
        parts = zip(self.columns, (along, gain, self.strength * (pulled - vowel_track[:, None])))
        return r, scatter_jacobian(len(z), self.n_params, parts)
