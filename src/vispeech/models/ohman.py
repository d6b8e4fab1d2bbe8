"""Öhman's (1967) look-ahead model, extended to any phone sequence as in Beskow (2004).

A vowel track v(t) joins the targets of successive vowels (and silences, which act as the
neutral mouth) with smoothstep cubics 3s² − 2s³ between their centres, held before the
first and after the last. Each consonant i adds a gesture toward its target c_i:

    z(t) = v(t) + Σ_i w_i · k_i(t) · (c_i − v(t))

with k_i rising from 0 at the previous segment's centre to 1 at τ_i and falling to 0 at the
next segment's centre (smoothstep halves, zero slope at all three points; the sequence's
start and end stand in for missing neighbours). The coarticulation factor w ∈ [0, 1] is per
consonant and channel: 1 reaches the consonant's target, 0 leaves the vowel track alone.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.base import PhoneTargetModel, register_model
from vispeech.models.targets import phone_rows, resolve_spec
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import LANGUAGES, SILENCE


def smoothstep(s: np.ndarray) -> np.ndarray:
    """3s² − 2s³ on s clipped to [0, 1]: 0 → 0 and 1 → 1 with zero slope at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


@register_model
class Ohman(PhoneTargetModel):
    """Vowel track plus consonant gestures. Parameters: ``w_c`` (per-phone spec of the
    coarticulation factor, values in [0, 1]) and ``targets`` (per-phone target overrides)."""

    name = "ohman"

    def __init__(self, params: Mapping | None = None, **options):
        super().__init__(params, **options)
        self._w = {language: resolve_spec(self._params["w_c"], language, self.channels) for language in LANGUAGES}
        if any(((w < 0) | (w > 1)).any() for w in self._w.values()):
            raise VispeechError("ohman w_c values must lie in [0, 1]")

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        t, centres, targets = seg.times, seg.centres, seg.targets
        vowel_track = self._vowel_track(seg)
        consonant = ~(seg.vowel | seg.silence)
        if not consonant.any():
            return self._track(vowel_track, fps)
        n = len(centres)
        knots = np.concatenate(([seg.starts[0]], centres, [seg.ends[-1]]))
        j = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, n)
        width = knots[j + 1] - knots[j]
        rise = smoothstep(np.divide(t - knots[j], width, out=np.ones_like(t), where=width > 0))
        w = self._w[seg.language][seg.rows]
        out = vowel_track.copy()
        for i, strength in ((j - 1, 1.0 - rise), (j, rise)):  # falling side of segment j-1, rising side of j
            active = (i >= 0) & (i < n)
            i = np.clip(i, 0, n - 1)
            active &= consonant[i]
            gain = (active * strength)[:, None] * w[i]
            out += gain * (targets[i] - vowel_track)
        return self._track(out, fps)

    def _vowel_track(self, seg) -> np.ndarray:
        anchor = seg.vowel | seg.silence
        if not anchor.any():
            silence = self.table.values(seg.language)[phone_rows(seg.language).keys[SILENCE, False]]
            return np.tile(silence, (len(seg.times), 1))
        centres, values = seg.centres[anchor], seg.targets[anchor]
        if len(centres) == 1:
            return np.tile(values[0], (len(seg.times), 1))
        m = np.clip(np.searchsorted(centres, seg.times, side="right") - 1, 0, len(centres) - 2)
        b = smoothstep((seg.times - centres[m]) / (centres[m + 1] - centres[m]))
        return values[m] + b[:, None] * (values[m + 1] - values[m])
