"""A phone sequence laid out for the data-free models: segments, their targets, frame times."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.phonetics.features import FEATURE_NAMES, phone_rows

_VOWEL = FEATURE_NAMES.index("vowel")
_SILENCE = FEATURE_NAMES.index("silence")


@dataclass(frozen=True)
class Segments:
    """One segment per phone of the gap-filled sequence, times in seconds.

    ``rows`` index :func:`vispeech.targets.tables.phone_rows`; ``targets`` and ``defined``
    (segments × channels) come from the model's target table; ``times`` are the frame
    times ``k / fps`` of the ``phones.n_frames(fps)`` output frames.
    """

    language: str
    starts: np.ndarray
    ends: np.ndarray
    rows: np.ndarray
    vowel: np.ndarray
    silence: np.ndarray
    targets: np.ndarray
    defined: np.ndarray
    times: np.ndarray

    @classmethod
    def build(cls, phones: PhoneSequence, fps: float, targets: np.ndarray, defined: np.ndarray) -> Segments:
        """The segments of ``phones`` with their rows of the per-row ``targets`` and ``defined`` tables."""
        phones.validate()
        n_frames = phones.n_frames(fps)
        filled = phones.with_gaps_filled().phones
        rows = phone_rows(phones.language)
        index = rows.indices([p.symbol for p in filled], [p.stress for p in filled])
        features = rows.features[index]
        return cls(
            language=phones.language,
            starts=np.array([p.start for p in filled]),
            ends=np.array([p.end for p in filled]),
            rows=index,
            vowel=features[:, _VOWEL] > 0,
            silence=features[:, _SILENCE] > 0,
            targets=targets[index],
            defined=defined[index],
            times=np.arange(n_frames) / fps,
        )

    def with_targets(self, targets: np.ndarray) -> Segments:
        """A copy whose targets are read from another per-row table."""
        return replace(self, targets=targets[self.rows])

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.starts + self.ends)

    @property
    def durations(self) -> np.ndarray:
        return self.ends - self.starts
