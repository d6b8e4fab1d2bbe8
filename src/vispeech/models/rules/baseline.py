"""The thesis's rule-based baseline: vowel and silence visemes at segment apices, Bézier easing.

The phone sequence is cut into segments, each a vowel or silence plus the consonants that
follow it up to the next vowel or silence. A segment's first frame is its apex and takes the
target (viseme) of its vowel or silence; consecutive apices are joined by the thesis's cubic
Bézier ease (control points (0.5a, 0) and (0.5a, 1), a = frames between apices). An extra
silence apex sits ``lead_in`` frames before the first audible phone after every silence, so
the mouth does not drift open during a pause. Consonants are left to the consonant overlays
of :func:`vispeech.postprocess.postprocess`.
"""

from __future__ import annotations

import numpy as np

from vispeech.alignment.phones import PhoneSequence, first_frame
from vispeech.errors import VispeechError
from vispeech.models.rules.phone_targets import PhoneTargetModel, family_defaults
from vispeech.motion.easing import bezier_ease
from vispeech.motion.track import Track
from vispeech.phonetics.features import phone_rows
from vispeech.phonetics.inventory import SILENCE


class Baseline(PhoneTargetModel):
    """Thesis baseline (section 3.3). Parameter ``lead_in``: frames (int ≥ 0) of the extra silence apex."""

    family = "baseline"
    defaults = family_defaults("baseline")

    def _check_params(self) -> None:
        super()._check_params()
        lead_in = self._params["lead_in"]
        if isinstance(lead_in, bool) or not isinstance(lead_in, int) or lead_in < 0:
            raise VispeechError(f"baseline lead_in must be a whole number of frames >= 0, got {lead_in!r}")

    def predict(self, phones: PhoneSequence, fps: float) -> Track:
        seg = self.segments(phones, fps)
        silence = self.tables(seg.language)["targets"][phone_rows(seg.language).keys[SILENCE, False]]
        first_frames = first_frame(seg.starts, fps).astype(float)
        anchor = seg.vowel | seg.silence
        apices: list[tuple[float, np.ndarray]] = []
        if not anchor[0]:
            apices.append((0.0, silence))
        lead_in = self._params["lead_in"]
        for i in range(len(anchor)):
            follows_silence = seg.silence[i - 1] if i > 0 else not anchor[0]
            if follows_silence and not seg.silence[i] and first_frames[i] - lead_in > apices[-1][0]:
                apices.append((first_frames[i] - lead_in, silence))
            if anchor[i]:
                apices.append((first_frames[i], seg.targets[i]))
        frames = np.array([f for f, _ in apices])
        values = np.array([v for _, v in apices])
        keep = np.append(frames[1:] > frames[:-1], True)  # of apices on one frame the last wins
        frames, values = frames[keep], values[keep]
        k = np.arange(len(seg.times), dtype=float)
        if len(frames) == 1:
            return self._track(np.repeat(values, len(k), axis=0), fps)
        j = np.clip(np.searchsorted(frames, k, side="right") - 1, 0, len(frames) - 2)
        y = bezier_ease(k - frames[j], frames[j + 1] - frames[j])
        out = values[j] + y[:, None] * (values[j + 1] - values[j])
        return self._track(out, fps)
