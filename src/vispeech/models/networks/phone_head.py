"""What an audio network's CTC head hears: the bilabials (/p b m/) in its phone posteriors.

A network trained with ``ctc_weight`` > 0 has a phone head whose posteriors are CTC's
spikes: a phone's probability peaks on one or two frames near its centre, blank elsewhere.
:func:`heard_bilabials` turns the summed posterior of the language's bilabial stops and
nasals into timed phones, so the bilabial overlay of the phone path
(:func:`vispeech.postprocess.postprocess`) can shut the lips on audio without a transcript.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.phonetics.features import FEATURE_NAMES, phone_features
from vispeech.phonetics.inventory import SILENCE

_BILABIAL = FEATURE_NAMES.index("bilabial")


def check_closure_params(threshold: object, length: object) -> None:
    """Raise :class:`VispeechError` unless ``threshold`` (a summed posterior; 0: hear none) is a
    number in [0, 1) and ``length`` (seconds) one in [0.01, 0.5]: the ``closure_threshold`` and
    ``closure_length`` of a model that hears bilabials."""
    if not (isinstance(threshold, int | float) and not isinstance(threshold, bool) and 0 <= threshold < 1):
        raise VispeechError(f"closure_threshold must be a number in [0, 1), got {threshold!r}")
    if not (isinstance(length, int | float) and not isinstance(length, bool) and 0.01 <= length <= 0.5):
        raise VispeechError(f"closure_length must lie in [0.01, 0.5] s, got {length!r}")


def bilabial_symbols(vocabulary: Sequence[str], language: str) -> list[str]:
    """The phones of ``vocabulary`` (a CTC head's labels) made with both lips: /p b m/."""
    return [s for s in vocabulary if phone_features(s, language)[_BILABIAL] > 0]


def heard_bilabials(
    posteriors: np.ndarray,
    vocabulary: Sequence[str],
    language: str,
    fps: float,
    threshold: float,
    length: float,
) -> PhoneSequence:
    """The bilabials a CTC head hears: one phone of ``length`` s centred on every peak of
    their summed posterior above ``threshold``.

    ``posteriors``: ``(frames, len(vocabulary) + 1)`` at ``fps``, column 0 CTC's blank and
    column i + 1 ``vocabulary[i]``. Each phone takes the most probable bilabial at its peak;
    peaks closer than ``length`` keep the stronger one. Silence covers the rest of the frames'
    span, so the sequence is never empty.
    """
    symbols = bilabial_symbols(vocabulary, language)
    columns = np.array([list(vocabulary).index(s) + 1 for s in symbols], dtype=int)
    end = max(len(posteriors), 1) / fps
    if not len(columns) or not len(posteriors):
        return PhoneSequence([Phone(SILENCE, 0.0, end)], language)
    p = posteriors[:, columns].sum(axis=1)
    padded = np.concatenate(([-np.inf], p, [-np.inf]))
    peaks = np.flatnonzero((p > threshold) & (p >= padded[:-2]) & (p > padded[2:]))
    kept: list[int] = []
    for t in peaks[np.argsort(-p[peaks], kind="stable")]:
        if all(abs(t - k) / fps >= length for k in kept):
            kept.append(int(t))
    phones, time = [], 0.0
    for t in sorted(kept):
        start, stop = max(0.0, t / fps - length / 2), t / fps + length / 2
        if start > time:
            phones.append(Phone(SILENCE, time, start))
        phones.append(Phone(symbols[int(np.argmax(posteriors[t, columns]))], start, stop))
        time = stop
    if end > time:
        phones.append(Phone(SILENCE, time, end))
    return PhoneSequence(phones, language)
