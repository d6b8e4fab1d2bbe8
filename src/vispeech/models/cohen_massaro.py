"""Cohen & Massaro's (1993) dominance model, with Beskow's (2004) per-phone exponent.

Each segment i (a phone of the gap-filled sequence, centre τ_i in seconds) pulls every
channel toward its target T_i with dominance

    D_i(t) = α_i · exp(−φ_i · |t − τ_i|^c_i)   for t < τ_i  (reach into preceding segments)
    D_i(t) = α_i · exp(−θ_i · |t − τ_i|^c_i)   for t ≥ τ_i  (reach into following segments)

and the output is the dominance-weighted mean z(t) = Σ D_i T_i / Σ D_i. T, α, θ, φ and c are
per phone and channel (time in seconds, so θ and φ are in s^-c). Only the ``window``
segments on either side of a frame's own segment are summed; beyond a few segments the
dominance is negligible, and the cost stays linear in the utterance length.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.base import PhoneTargetModel, register_model
from vispeech.models.targets import resolve_spec
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import LANGUAGES

_PARAMETERS = ("alpha", "theta", "phi", "c")


@register_model
class CohenMassaro(PhoneTargetModel):
    """Dominance-function coarticulation. Parameters: per-phone specs ``alpha``, ``theta``,
    ``phi``, ``c`` (see :func:`vispeech.models.targets.resolve_spec`), ``window`` (segments),
    ``targets`` (per-phone target overrides)."""

    name = "cohen-massaro"

    def __init__(self, params: Mapping | None = None, **options):
        super().__init__(params, **options)
        window = self._params["window"]
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise VispeechError(f"cohen-massaro window must be a whole number of segments >= 1, got {window!r}")
        self._tables: dict[str, tuple[np.ndarray, ...]] = {}
        for language in LANGUAGES:
            alpha, theta, phi, c = (resolve_spec(self._params[p], language, self.channels) for p in _PARAMETERS)
            if (alpha <= 0).any() or (theta < 0).any() or (phi < 0).any() or (c <= 0).any():
                raise VispeechError("cohen-massaro needs alpha > 0, theta >= 0, phi >= 0 and c > 0")
            self._tables[language] = (np.log(alpha), theta, phi, c)
        self._unit_exponent = all((table[3] == 1.0).all() for table in self._tables.values())

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        log_alpha, theta, phi, c = (a[seg.rows] for a in self._tables[seg.language])
        n = len(seg.rows)
        window = np.arange(-self._params["window"], self._params["window"] + 1)
        own = np.minimum(np.searchsorted(seg.ends, seg.times, side="right"), n - 1)
        idx = own[:, None] + window  # frames × window
        valid = (idx >= 0) & (idx < n)
        idx = np.clip(idx, 0, n - 1)
        dt = seg.times[:, None] - seg.centres[idx]
        distance = np.abs(dt)[:, :, None]
        if not self._unit_exponent:
            distance = distance ** c[idx]
        rate = np.where((dt < 0)[:, :, None], phi[idx], theta[idx])
        log_d = log_alpha[idx] - rate * distance
        log_d[~valid] = -np.inf
        d = np.exp(log_d - log_d.max(axis=1, keepdims=True))
        out = np.einsum("fkc,fkc->fc", d, seg.targets[idx]) / d.sum(axis=1)
        return self._track(out, fps)
