"""Cohen & Massaro's (1993) dominance model, with Beskow's (2004) per-phone exponent.

Each segment i (a phone of the gap-filled sequence, centre τ_i in seconds) pulls every
channel toward its target T_i with dominance

    D_i(t) = α_i · exp(−φ_i · |t − τ_i|^c_i)   for t < τ_i  (reach into preceding segments)
    D_i(t) = α_i · exp(−θ_i · |t − τ_i|^c_i)   for t ≥ τ_i  (reach into following segments)

and the output is the dominance-weighted mean z(t) = Σ D_i T_i / Σ D_i. T, α, θ, φ and c are
per phone and channel (time in seconds, so θ and φ are in s^-c). Only the ``window``
segments on either side of a frame's own segment are summed; beyond a few segments the
dominance is negligible, and the cost stays linear in the utterance length.

:meth:`CohenMassaro.fit` estimates all five per phone and channel from recorded tracks
(see :mod:`vispeech.models.rules.dominance_fit`).
"""

from __future__ import annotations

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.models.fitting import FitRun
from vispeech.models.rules.dominance_fit import FitData, PhoneTying, Recording, fit_channels, scatter_jacobian
from vispeech.models.rules.phone_targets import PhoneTargetModel, family_defaults
from vispeech.models.rules.segments import Segments
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import LANGUAGES
from vispeech.targets.tables import resolve_spec

_PARAMETERS = ("alpha", "theta", "phi", "c")

_UNIT = 0.1
"""Seconds: the fit measures distances from segment centres in this unit, so that its θ and φ
(the exponent at 0.1 s) barely depend on c; they are turned back into s^-c afterwards."""

BOUNDS: dict[str, tuple[float, float]] = {
    "alpha": (1e-4, 1e4),
    "theta": (1e-3, 1e3),
    "phi": (1e-3, 1e3),
    "c": (0.2, 5.0),
}
"""The range :meth:`CohenMassaro.fit` keeps each dominance parameter in (θ and φ as the
exponent at 0.1 s, ``θ·0.1^c``; targets stay in [0, 1])."""


class CohenMassaro(PhoneTargetModel):
    """Dominance-function coarticulation.

    Hyper-parameters: per-phone specs ``alpha``, ``theta``, ``phi``, ``c`` (see
    :func:`vispeech.targets.tables.resolve_spec`), ``window`` (segments), ``targets``
    (per-phone target overrides); for :meth:`fit`: ``channels`` (``None``: the model's
    channels every training track has), ``max_iterations`` and ``patience`` (iterations
    without a better validation error before a channel stops).
    """

    family = "cohen-massaro"
    defaults = {**family_defaults("cohen-massaro"), "channels": None, "max_iterations": 100, "patience": 3}
    trainable = True
    table_names = ("targets", *_PARAMETERS)

    def _check_params(self) -> None:
        super()._check_params()
        self._check_fit_params()
        window = self._params["window"]
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise VispeechError(f"cohen-massaro window must be a whole number of segments >= 1, got {window!r}")
        for language in LANGUAGES:
            alpha, theta, phi, c = (self._authored(language)[p] for p in _PARAMETERS)
            if (alpha <= 0).any() or (theta < 0).any() or (phi < 0).any() or (c <= 0).any():
                raise VispeechError("cohen-massaro needs alpha > 0, theta >= 0, phi >= 0 and c > 0")

    def _authored_tables(self, language: str) -> dict[str, np.ndarray]:
        specs = {p: resolve_spec(self._params[p], language, self.channels) for p in _PARAMETERS}
        return {**super()._authored_tables(language), **specs}

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        tables = self.tables(seg.language)
        alpha, theta, phi, c = (tables[p][seg.rows] for p in _PARAMETERS)
        idx, dt, valid = _window(seg, self._params["window"])
        distance = np.abs(dt)[:, :, None]
        if not (c == 1.0).all():
            distance = distance ** c[idx]
        d = _dominance(np.log(alpha)[idx], theta[idx], phi[idx], distance, (dt < 0)[:, :, None], valid)
        out = np.einsum("fkc,fkc->fc", d, seg.targets[idx]) / d.sum(axis=1)
        return self._track(out, fps)

    def _fit(self, corpus, run: FitRun) -> CohenMassaro:
        """Estimate T, α, θ, φ and c per phone symbol and channel by least squares; returns ``self``.

        Fits the ``train`` split of a corpus with splits and stops each channel early on its
        ``validation`` split (any other iterable of utterances: all of it, no early stop).
        Each channel is fitted separately at the tracks' own frame times. Phones and channels
        the training data lacks keep their authored values. Learns ``tables_`` (per
        language, the per-row T, α, θ, φ, c), ``fitted_channels_`` and ``history_``.
        """
        run.in_one_go(self.family)
        p = self._params
        data = FitData.gather(self, corpus, p["channels"])
        tying = PhoneTying.of(data.language, data.train)
        window = p["window"]
        train = _Design(data.train, window, tying)
        held = _Design(data.validation, window, tying) if any(len(r.values) for r in data.validation) else None
        n = len(tying)
        first = tying.first_rows
        columns = [self.channels.index(c) for c in data.channels]
        authored = self._authored(data.language)
        targets = authored["targets"]
        log_alpha, theta, phi, c = np.log(authored["alpha"]), authored["theta"], authored["phi"], authored["c"]
        means = tying.frame_means(data.train, targets[first][:, columns])
        theta, phi = theta * _UNIT**c, phi * _UNIT**c  # rates per distance in units of _UNIT
        lower = np.concatenate([np.zeros(n)] + [np.full(n, np.log(BOUNDS[q][0])) for q in _PARAMETERS])
        upper = np.concatenate([np.ones(n)] + [np.full(n, np.log(BOUNDS[q][1])) for q in _PARAMETERS])
        # α is defined up to a common factor: hold that of the phone with the most frames
        anchor = np.argmax(np.bincount(np.concatenate([tying.column[r.own_rows] for r in data.train]), minlength=n))
        lower[n + anchor] = upper[n + anchor] = 0.0

        def start(j: int, m: int) -> tuple[tuple, np.ndarray]:
            base = (targets[:, m], log_alpha[:, m], theta[:, m], phi[:, m], c[:, m])
            with np.errstate(divide="ignore"):
                x0 = np.concatenate(
                    [
                        means[:, j],
                        log_alpha[first, m],
                        np.log(theta[first, m]),
                        np.log(phi[first, m]),
                        np.log(c[first, m]),
                    ]
                )
            return base, x0

        fitted = fit_channels(self, data, start, lower, upper, train, held, run.progress)
        learned = {name: values.copy() for name, values in authored.items()}
        for channel, m in zip(data.channels, columns):
            blocks = [fitted[channel][k * n : (k + 1) * n] for k in range(5)]
            exponent = tying.expand(learned["c"][:, m], np.exp(blocks[4]))
            learned["targets"][:, m] = tying.expand(learned["targets"][:, m], blocks[0])
            learned["alpha"][:, m] = tying.expand(learned["alpha"][:, m], np.exp(blocks[1]))
            for name, block in (("theta", blocks[2]), ("phi", blocks[3])):
                scaled = tying.expand(learned[name][:, m] * _UNIT ** learned["c"][:, m], np.exp(block))
                learned[name][:, m] = scaled / _UNIT**exponent
            learned["c"][:, m] = exponent
        self.tables_ = {data.language: learned}
        return self


def _window(seg: Segments, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each frame time of ``seg``: the segments within ``window`` of its own (indices,
    frames × 2·window+1), the signed distances t − τ to their centres (seconds) and which exist."""
    n = len(seg.rows)
    own = np.minimum(np.searchsorted(seg.ends, seg.times, side="right"), n - 1)
    idx = own[:, None] + np.arange(-window, window + 1)
    valid = (idx >= 0) & (idx < n)
    idx = np.clip(idx, 0, n - 1)
    return idx, seg.times[:, None] - seg.centres[idx], valid


def _dominance(log_alpha, theta, phi, distance, before, valid: np.ndarray) -> np.ndarray:
    """Dominances exp(log α − (φ if ``before`` else θ)·distance) along axis 1, scaled so that
    each frame's largest is 1 (computed in log space); 0 where not ``valid``."""
    log_d = log_alpha - np.where(before, phi, theta) * distance
    log_d[~valid] = -np.inf
    return np.exp(log_d - log_d.max(axis=1, keepdims=True))


class _Design:
    """The frames of some recordings laid out for one channel's fit: per frame the window
    segments' phone rows, distances and Jacobian columns (T, log α, log θ, log φ, log c)."""

    def __init__(self, recordings: list[Recording], window: int, tying: PhoneTying):
        layouts = [_window(r.segments, window) for r in recordings]
        self.rows = np.concatenate([r.segments.rows[idx] for r, (idx, _, _) in zip(recordings, layouts)])
        dt = np.concatenate([dt for _, dt, _ in layouts])
        self.valid = np.concatenate([valid for _, _, valid in layouts])
        self.values = np.concatenate([r.values for r in recordings])
        self.before = dt < 0
        self.distance = np.abs(dt) / _UNIT
        self.log_distance = np.log(self.distance, out=np.zeros_like(dt), where=self.distance > 0)
        self.tying = tying
        n = len(tying)
        column = np.where(self.valid, tying.columns(self.rows), -1)
        shifted = [np.where(column >= 0, column + k * n, -1) for k in range(5)]
        shifted[2] = np.where(self.before, -1, shifted[2])  # θ acts after the centre
        shifted[3] = np.where(self.before, shifted[3], -1)  # φ before it
        self.columns = shifted

    def residuals(
        self, base: tuple[np.ndarray, ...], channel: int, x: np.ndarray, jacobian: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """z − y on these frames for parameters ``x`` (T, log α, log θ, log φ, log c per
        fitted symbol) over the per-row tables ``base`` (T, log α, θ, φ, c), and ∂z/∂x."""
        n = len(self.tying)
        blocks = [x[k * n : (k + 1) * n] for k in range(5)]
        expand = self.tying.expand
        target = expand(base[0], blocks[0])[self.rows]
        log_alpha = expand(base[1], blocks[1])[self.rows]
        theta, phi, c = (expand(base[k], np.exp(blocks[k]))[self.rows] for k in (2, 3, 4))
        powered = self.distance**c
        d = _dominance(log_alpha, theta, phi, powered, self.before, self.valid)
        d /= d.sum(axis=1, keepdims=True)
        z = np.einsum("fk,fk->f", d, target)
        r = z - self.values[:, channel]
        if not jacobian:
            return r, None
        pull = d * (target - z[:, None])  # ∂z/∂log α
        spread = -np.where(self.before, phi, theta) * powered * pull  # ∂z/∂log θ or ∂z/∂log φ
        parts = zip(self.columns, (d, pull, spread, spread, spread * c * self.log_distance))
        return r, scatter_jacobian(len(z), 5 * n, parts)
