"""Tongue channels from the phones' articulatory features, for every model until data can train them.

No corpus here tracks the tongue (GRID's video tracker has no tongue shape), so the tongue
comes from what the phones say it does, in four channels:

- ``tongueOut`` (ARKit): the tip between the teeth, for dental fricatives (/θ ð/): 0.6;
- ``tongueTipUp``: the tip raised to the ridge or the teeth, for coronal stops, nasals and
  laterals (/t d n l/, the Swedish retroflexes /ʈ ɖ ɳ ɭ/): 1; coronal fricatives (/s z ʃ ʂ/):
  0.7; coronal approximants (/r ɹ/): 0.5;
- ``tongueBodyUp``: the body raised to the velum or the palate, for velar consonants (/k g ŋ x/):
  1; palatal ones (/j ç ɲ/): 0.7; close front vowels: 0.3;
- ``tongueBack``: the body drawn back, for back vowels (0.5 for close ones, 0.3 otherwise) and
  uvular and pharyngeal consonants (0.5).

Each phone's value is held on its anchor frame (the frame nearest its centre) and the channel
goes linearly from one phone's anchor frame to the next: the tongue moves on between phones as
the lips do. A track that already has ``tongueOut`` (the rule models' targets) keeps the larger
of the two. ``tongueTipUp``, ``tongueBodyUp`` and ``tongueBack`` are vispeech's own channels,
not ARKit's: JSON carries them, Live Link Face CSV only ``tongueOut``.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.motion.arkit import TONGUE_CHANNELS
from vispeech.motion.track import Track
from vispeech.phonetics.features import FEATURE_NAMES, phone_rows
from vispeech.postprocess.overlays import anchor_frames


def tongue_targets(features: np.ndarray) -> np.ndarray:
    """Per phone (rows of feature vectors, :data:`~vispeech.phonetics.features.FEATURE_NAMES`), its
    values of :data:`TONGUE_CHANNELS` (see the module docstring)."""
    f = {name: features[:, k] > 0 for k, name in enumerate(FEATURE_NAMES)}
    level = {name: features[:, k] for k, name in enumerate(FEATURE_NAMES)}
    consonant = ~f["vowel"] & ~f["silence"]
    coronal = f["alveolar"] | f["retroflex"] | f["dental"] | f["postalveolar"]
    out = np.where(consonant & f["dental"] & f["fricative"] & ~f["stop"], 0.6, 0.0)
    closure = f["stop"] | f["nasal"] | f["lateral"]
    tip = np.select(
        [consonant & coronal & closure, consonant & coronal & f["fricative"], consonant & coronal & f["approximant"]],
        [1.0, 0.7, 0.5],
        0.0,
    )
    tip = np.where(out > 0, 0.0, tip)
    body = np.select(
        [
            consonant & f["velar"] & ~f["approximant"],
            consonant & f["palatal"] & ~f["postalveolar"],
            f["vowel"] & (level["open"] == 0) & (level["front"] >= 1),
        ],
        [1.0, 0.7, 0.3],
        0.0,
    )
    back = np.select(
        [
            f["vowel"] & (level["front"] == 0) & (level["open"] == 0),
            f["vowel"] & (level["front"] == 0),
            consonant & f["glottal"] & f["fricative"] & f["voiced"],
        ],
        [0.5, 0.3, 0.5],
        0.0,
    )
    return np.column_stack([out, tip, body, back])


@cache
def _row_targets(language: str) -> np.ndarray:
    """:func:`tongue_targets` of every phone row of ``language`` (a row's targets are its own)."""
    targets = tongue_targets(phone_rows(language).features)
    targets.setflags(write=False)
    return targets


def tongue_channels(track: Track, phones: PhoneSequence) -> Track:
    """``track`` with :data:`TONGUE_CHANNELS` from ``phones`` (added, or for ``tongueOut`` the larger)."""
    spoken = [p for p in phones if not p.is_silence]
    n = track.n_frames
    values = np.zeros((n, len(TONGUE_CHANNELS)))
    if spoken and n:
        rows = phone_rows(phones.language)
        targets = _row_targets(phones.language)[rows.indices([p.symbol for p in spoken], [p.stress for p in spoken])]
        starts = np.array([p.start for p in spoken]) - track.start_time
        ends = np.array([p.end for p in spoken]) - track.start_time
        anchors = anchor_frames(starts, ends, track.fps, n)
        # silence: the tongue at rest from the frame after a phone's end to the frame before the next's start
        keys = [(int(a), t) for a, t in zip(anchors, targets)]
        rest = np.zeros(len(TONGUE_CHANNELS))
        for end, start in zip(ends[:-1], starts[1:]):
            if start - end > 2.0 / track.fps:  # a pause between the phones
                keys += [(int(np.ceil(end * track.fps)), rest), (int(np.floor(start * track.fps)), rest)]
        first, last = int(np.floor(starts[0] * track.fps)), int(np.ceil(ends[-1] * track.fps))
        held = set(anchors.tolist())
        keys += [(k, rest) for k in (0, first, last, n - 1) if 0 <= k < n and k not in held]
        keys.sort(key=lambda item: item[0])
        frames = np.array([k for k, _ in keys], dtype=float)
        points = np.array([v for _, v in keys])
        for c in range(len(TONGUE_CHANNELS)):
            values[:, c] = np.interp(np.arange(n), frames, points[:, c])
        values[anchors] = np.maximum(values[anchors], targets)  # each phone's own value on its frame
    keep = [c for c in track.channels if c not in TONGUE_CHANNELS[1:]]
    out = track.select(keep)
    if "tongueOut" in out.channels:
        k = out.index("tongueOut")
        out.values[:, k] = np.maximum(out.values[:, k], values[:, 0])
        added, extra = list(TONGUE_CHANNELS[1:]), values[:, 1:]
    else:
        added, extra = list(TONGUE_CHANNELS), values
    return Track(np.column_stack([out.values, extra]), (*out.channels, *added), track.fps, track.start_time)
