"""Consonant overlays and the upper-lip overlay of the thesis (section 4, steps 6 and 7).

Every consonant's viseme is its target in :mod:`vispeech.targets.tables`, restricted to the
channels the consonant defines. It is blended in with strength s(t), x ← x + s·(v − x):
a Bézier fade-in of ``fade_in`` phone lengths that reaches 1 at the phone's onset, full
strength up to the phone's *anchor frame*, then a Bézier fade-out of a per-consonant number
of phone lengths. The anchor frame is the frame inside the phone nearest its centre (for a
phone shorter than a frame, the frame nearest its centre). As in Öhman's model, a fade
reaches no further than the full-strength stretch of the neighbouring consonants or the
anchor frame of the neighbouring vowel (the curve is compressed to fit): every consonant
shows its viseme on its anchor frame and every vowel its own shape on its anchor frame, so
/p b m/ close the lips (without a mouth kept shut through "my mom") and /f v/ bring the
lower lip to the upper teeth. Only consonants
sharing an anchor frame compete there: overlays go from the most open viseme to the most
closed, bilabials last, so the tightest constriction wins. An overlay never raises jawOpen
(x ← min(x, blend)), so the jaw's peaks stay with the vowels.

Options for models that learned the jaw from recordings: ``features`` overlays only the
consonants with one of the given articulatory features (e.g. bilabial and labiodental), and
``keep_jaw`` leaves jawOpen alone and blends mouthClose towards ``jawOpen − (v_jawOpen −
v_mouthClose)`` instead, so each viseme's lip opening (jawOpen − mouthClose) is reached at
whatever height the model put the jaw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cache

import numpy as np

from vispeech.alignment.phones import PhoneSequence, first_frame
from vispeech.errors import VispeechError
from vispeech.motion.arkit import lip_aperture
from vispeech.motion.easing import bezier_ease
from vispeech.motion.track import Track
from vispeech.phonetics.features import FEATURE_NAMES, phone_rows
from vispeech.phonetics.inventory import is_vowel
from vispeech.targets.tables import TARGET_CHANNELS, default_targets, resolve_spec

DEFAULT_FADE_OUT: Mapping = {
    "default": 1.5,
    "sv:t": 1.0,
    "sv:d": 1.0,
    "sv:rt": 1.0,
    "sv:rd": 1.0,
    "en:T": 1.0,
    "en:D": 1.0,
}
"""Fade-out lengths in phone lengths (a per-phone spec): 1.5 as in the thesis, shorter for /t d/."""

UPPER_LIP_CHANNELS = ("mouthUpperUpLeft", "mouthUpperUpRight")
UPPER_LIP_RISE = 5.0
"""Frames the upper-lip lift takes to reach full strength."""

_VOWEL = FEATURE_NAMES.index("vowel")
_SILENCE = FEATURE_NAMES.index("silence")


@cache
def _default_fade_out(language: str) -> np.ndarray:
    """:data:`DEFAULT_FADE_OUT` over every phone row of ``language``."""
    return resolve_spec(DEFAULT_FADE_OUT, language)


@cache
def _overlaid_rows(language: str, features: tuple[str, ...] | None) -> np.ndarray:
    """Which phone rows of ``language`` get an overlay: consonants, with one of ``features`` if given."""
    rows = phone_rows(language)
    overlaid = (rows.features[:, _VOWEL] == 0) & (rows.features[:, _SILENCE] == 0)
    if features is not None:
        unknown = [f for f in features if f not in FEATURE_NAMES]
        if unknown:
            raise VispeechError(f"unknown articulatory features {', '.join(unknown)} for overlays")
        overlaid &= (rows.features[:, [FEATURE_NAMES.index(f) for f in features]] > 0).any(axis=1)
    overlaid.setflags(write=False)
    return overlaid


@cache
def _viseme_aperture(language: str) -> np.ndarray:
    """The lip aperture of every phone row's viseme (its defined targets, others 0): the overlays' order."""
    table = default_targets()
    visemes = np.where(table.defined(language), table.values(language), 0.0)
    return lip_aperture(Track(visemes, TARGET_CHANNELS, 1.0))


def anchor_frames(starts: np.ndarray, ends: np.ndarray, fps: float, n_frames: int) -> np.ndarray:
    """Per phone, the frame inside [start, end) nearest its centre, or the nearest frame if none is inside.

    Times are seconds from the first frame; frame k sits at k / fps.
    """
    first = first_frame(starts, fps).astype(float)
    last = first_frame(ends, fps).astype(float) - 1
    centre = np.round(0.5 * (starts + ends) * fps)
    inside = np.clip(centre, first, np.maximum(first, last))
    return np.clip(np.where(last >= first, inside, centre), 0, n_frames - 1).astype(int)


def consonant_overlays(
    track: Track,
    phones: PhoneSequence,
    fade_in: float = 1.5,
    fade_out: Mapping | None = None,
    features: Sequence[str] | None = None,
    keep_jaw: bool = False,
) -> Track:
    """``track`` with every consonant's viseme blended in (see the module docstring).

    ``fade_in`` is in phone lengths; ``fade_out`` is a per-phone spec of phone lengths
    (default :data:`DEFAULT_FADE_OUT`). ``features``: overlay only consonants with one of
    these articulatory features (``None``: every consonant). ``keep_jaw``: leave jawOpen as
    it is and reach each viseme's lip opening through mouthClose. Channels the visemes set
    but the track lacks are added.
    """
    language = phones.language
    rows = phone_rows(language)
    index = all_rows = rows.indices(phones.symbols, [p.stress for p in phones])
    is_consonant = _overlaid_rows(language, None if features is None else tuple(features))[index]
    consonants = [p for p, keep in zip(phones, is_consonant) if keep]
    index = index[is_consonant]
    out = track.select(track.channels + tuple(c for c in TARGET_CHANNELS if c not in track.channels))
    if not consonants:
        return out
    table = default_targets()
    fade_out_lengths = (_default_fade_out(language) if fade_out is None else resolve_spec(fade_out, language))[index]

    starts = np.array([p.start for p in consonants]) - out.start_time
    ends = np.array([p.end for p in consonants]) - out.start_time
    vowels = [p for p, vowel in zip(phones, rows.features[all_rows, _VOWEL] > 0) if vowel]
    peak_from, peak_to, rise, fall = _fades(starts, ends, vowels, out, fade_in, fade_out_lengths)
    lo, hi, strengths = _strengths(peak_from, peak_to, rise, fall, out.n_frames)

    aperture = _viseme_aperture(language)[index]
    bilabial = rows.features[index, FEATURE_NAMES.index("bilabial")] > 0
    order = sorted(range(len(consonants)), key=lambda i: (-aperture[i], bilabial[i], starts[i]))
    _blend_visemes(
        out, table.values(language)[index], table.defined(language)[index], order, lo, hi, strengths, keep_jaw
    )
    return out


def _fades(
    starts: np.ndarray, ends: np.ndarray, vowels: list, out: Track, fade_in: float, fade_out_lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per consonant (``starts``, ``ends``: seconds from ``out``'s first frame), in frames: the
    full-strength stretch (``peak_from`` to ``peak_to``, from its onset to its anchor frame) and
    the fade-in and fade-out lengths before and after it, cut short by Öhman's rule."""
    fps, n = out.fps, out.n_frames
    length = (ends - starts) * fps  # phone lengths in frames
    onset = starts * fps
    anchor = anchor_frames(starts, ends, fps, n)
    peak_from, peak_to = np.minimum(onset, anchor), np.maximum(onset, anchor)
    # Öhman's rule: a consonant's fades reach no further than its neighbours' peaks: the
    # full-strength stretch of the next consonant, or the anchor frame of the next vowel
    # (so that a vowel between two bilabials still opens the mouth at its centre)
    vowel_anchor = anchor_frames(
        np.array([p.start for p in vowels]) - out.start_time,
        np.array([p.end for p in vowels]) - out.start_time,
        fps,
        n,
    ).astype(float)
    before = np.searchsorted(vowel_anchor, peak_from, side="left") - 1
    after = np.searchsorted(vowel_anchor, peak_to, side="right")
    previous_vowel = np.where(before >= 0, vowel_anchor[np.maximum(before, 0)], -np.inf) if vowels else -np.inf
    next_vowel = (
        np.where(after < len(vowels), vowel_anchor[np.minimum(after, len(vowels) - 1)], np.inf) if vowels else np.inf
    )
    previous_peak = np.maximum(np.concatenate(([-np.inf], peak_to[:-1])), previous_vowel)
    next_peak = np.minimum(np.concatenate((peak_from[1:], [np.inf])), next_vowel)
    rise = np.clip(np.minimum(fade_in * length, peak_from - previous_peak), 0.0, None)
    fall = np.clip(np.minimum(fade_out_lengths * length, next_peak - peak_to), 0.0, None)
    return peak_from, peak_to, rise, fall


def _strengths(
    peak_from: np.ndarray, peak_to: np.ndarray, rise: np.ndarray, fall: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Per consonant, the first and last frames it reaches (``lo``, ``hi``, within the ``n``
    frames) and its strength on each of them: the Bézier fade in, 1 over its peak, the fade out."""
    lo = np.maximum(np.ceil(peak_from - rise), 0).astype(int)
    hi = np.minimum(np.floor(peak_to + fall), n - 1).astype(int)
    counts = np.maximum(hi - lo + 1, 0)
    owner = np.repeat(np.arange(len(lo)), counts)  # one entry per (consonant, frame) pair
    k = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + lo[owner]).astype(float)
    rising = k < peak_from[owner]
    y = bezier_ease(
        np.where(rising, k - (peak_from - rise)[owner], k - peak_to[owner]),
        np.where(rising, rise[owner], fall[owner]),
    )
    strength = np.where(rising, y, 1.0 - y)
    strength[~rising & (k <= peak_to[owner])] = 1.0
    return lo, hi, np.split(strength, np.cumsum(counts)[:-1])


def _blend_visemes(
    out: Track,
    visemes: np.ndarray,
    defined: np.ndarray,
    order: Sequence[int],
    lo: np.ndarray,
    hi: np.ndarray,
    strengths: Sequence[np.ndarray],
    keep_jaw: bool,
) -> None:
    """Blend each consonant's viseme (its ``defined`` channels) into ``out`` over frames ``lo`` to
    ``hi`` with its ``strengths``, one after another in ``order``; jawOpen never rises, and with
    ``keep_jaw`` is left alone, mouthClose keeping the viseme's lip opening under the jaw."""
    columns = np.array([out.channels.index(c) for c in TARGET_CHANNELS])
    jaw, close = TARGET_CHANNELS.index("jawOpen"), TARGET_CHANNELS.index("mouthClose")
    values = out.values
    for i in order:
        frames = slice(lo[i], hi[i] + 1)
        s = strengths[i][:, None]
        channels = np.flatnonzero(defined[i])
        if keep_jaw:
            channels = channels[channels != jaw]
        cols = columns[channels]
        current = values[frames, cols]
        target = np.repeat(visemes[i, channels][None], len(current), axis=0)
        if keep_jaw and defined[i, jaw] and close in channels:
            lip_gap = visemes[i, jaw] - visemes[i, close]
            target[:, channels.tolist().index(close)] = np.maximum(values[frames, columns[jaw]] - lip_gap, 0.0)
        blended = current + s * (target - current)
        if jaw in channels:  # an overlay never raises the jaw
            k = channels.tolist().index(jaw)
            blended[:, k] = np.minimum(current[:, k], blended[:, k])
        values[frames, cols] = blended


def upper_lip_overlay(track: Track, phones: PhoneSequence, amount: float) -> Track:
    """Lift the upper lip by up to ``amount`` during speech (thesis section 4, step 7).

    In each stretch of speech between silences the lift rises over
    :data:`UPPER_LIP_RISE` frames and then fades out until the stretch ends; it starts
    afresh at every vowel onset (the running maximum of the curves). The curves are the
    thesis's Bézier with control points (0.6a, 0) and (0.75a, 1).
    """
    out = track.select(track.channels + tuple(c for c in UPPER_LIP_CHANNELS if c not in track.channels))
    fps, k = out.fps, np.arange(out.n_frames, dtype=float)
    strength = np.zeros(out.n_frames)
    run: list = []
    for phone in list(phones.with_gaps_filled()) + [None]:
        if phone is not None and not phone.is_silence:
            run.append(phone)
            continue
        if run:
            end = (run[-1].end - out.start_time) * fps
            renewals = [run[0].start] + [p.start for p in run[1:] if is_vowel(p.symbol, phones.language)]
            for start in renewals:
                r = (start - out.start_time) * fps
                top = r + UPPER_LIP_RISE
                curve = np.where(
                    k < top,
                    bezier_ease(k - r, UPPER_LIP_RISE, 0.6, 0.75),
                    1.0 - bezier_ease(k - top, max(end - top, 0.0), 0.6, 0.75),
                )
                curve[(k < r) | (k > end)] = 0.0
                strength = np.maximum(strength, curve)
        run = []
    for channel in UPPER_LIP_CHANNELS:
        out.values[:, out.index(channel)] += amount * strength
    return out


VOWEL_OPENING = 0.8
"""Share of an utterance's open-vowel lip opening that every open vowel reaches (see :func:`open_vowels`)."""

_OPEN = FEATURE_NAMES.index("open")
_LIP_CLOSING = ("bilabial", "labiodental")


def open_vowels(track: Track, phones: PhoneSequence, share: float = VOWEL_OPENING) -> Track:
    """``track`` with the lips open on the anchor frame of every vowel next to a bilabial or
    labiodental, however short the vowel.

    A network that learned from speech at 25 fps may leave a one-frame vowel between two
    bilabials shut (espeak-ng's Swedish "mamma" gives its stressed /a/ 44 ms). The reference
    is the utterance's own open-vowel opening: the 95th percentile of the lip aperture
    (:func:`vispeech.motion.arkit.lip_aperture`) on its vowels' anchor frames. Such a vowel,
    with the ``open`` feature o (0, 0.5, 1), reaches at least ``share · (0.25 + 0.75·o)`` of it: the
    missing opening comes from mouthClose first, then from jawOpen. A frame that is also a
    bilabial's or labiodental's anchor frame keeps its closure. Tracks without jawOpen and
    mouthClose, and utterances without vowels, are returned as they are.
    """
    if not {"jawOpen", "mouthClose"} <= set(track.channels) or share <= 0:
        return track
    rows = phone_rows(phones.language)
    spoken = [p for p in phones if not p.is_silence]
    if not spoken:
        return track
    index = rows.indices([p.symbol for p in spoken], [p.stress for p in spoken])
    features = rows.features[index]
    starts = np.array([p.start for p in spoken]) - track.start_time
    ends = np.array([p.end for p in spoken]) - track.start_time
    anchors = anchor_frames(starts, ends, track.fps, track.n_frames)
    vowel = features[:, _VOWEL] > 0
    if not vowel.any():
        return track
    closing = np.zeros(len(spoken), dtype=bool)
    for name in _LIP_CLOSING:
        closing |= features[:, FEATURE_NAMES.index(name)] > 0
    held = set(anchors[closing].tolist())
    beside = np.zeros(len(spoken), dtype=bool)  # next to a consonant that closes the lips
    beside[1:] |= closing[:-1]
    beside[:-1] |= closing[1:]
    out = track.copy()
    jaw, close = out.index("jawOpen"), out.index("mouthClose")
    aperture = lip_aperture(out)
    reference = float(np.percentile(aperture[anchors[vowel]], 95))
    for k, openness in zip(anchors[vowel & beside], features[vowel & beside, _OPEN]):
        if k in held:
            continue
        deficit = share * reference * (0.25 + 0.75 * openness) - aperture[k]
        if deficit <= 0:
            continue
        cut = min(deficit, out.values[k, close])
        out.values[k, close] -= cut
        out.values[k, jaw] += deficit - cut
    return out
