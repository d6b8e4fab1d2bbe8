"""Named post-processing presets: what a model recommends for its output, by name.

A model says which preset suits it (:attr:`vispeech.models.contract.Estimator.postprocessing`);
:meth:`vispeech.postprocess.PostprocessConfig.from_preset` turns the name into settings. Each
preset is a set of :class:`~vispeech.postprocess.PostprocessConfig` fields over its defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

PRESETS: Mapping[str, Mapping] = MappingProxyType(
    {
        "authored": {},
        "learned-jaw": {
            "jaw_shift": 0.0,
            "ceilings": {},
            "overlay_features": ("bilabial", "labiodental"),
            "keep_jaw": True,
        },
        "audio": {
            "jaw_shift": 0.0,
            "ceilings": {},
            "overlays": False,
            "jaw_peaks_in_vowels": False,
            "vowel_opening": 0.0,
            "tongue": False,
        },
        "audio-closures": {
            "jaw_shift": 0.0,
            "ceilings": {},
            "overlay_features": ("bilabial",),
            "keep_jaw": True,
            "jaw_peaks_in_vowels": False,
            "vowel_opening": 0.0,
            "tongue": False,
        },
    }
)
"""``authored``: every step with its defaults, tuned for the iPhone-scale authored targets of the
data-free models (jaw range shift, soft ceilings, all consonant overlays). ``learned-jaw``: for
models fitted to recordings: no jaw shift or absolute ceilings, overlays only for /p b m/ and
/f v/, closing the lips through mouthClose and leaving the learned jaw alone. ``audio``: for
models that animate audio without phones: nothing keyed on phones (no overlays, no vowel
opening, no tongue, no jaw confinement), only ``mouthClose ≤ jawOpen``, clipping and the
mouth at rest where the audio is quiet.
``audio-closures``: ``audio`` plus the /p b m/ overlay of ``learned-jaw``, for audio networks
that hear the bilabials themselves (their phone head gives phones for the bilabials only)."""
