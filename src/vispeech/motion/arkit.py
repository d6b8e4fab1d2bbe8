"""ARKit blend-shape names, channel groups and the lip aperture."""

import numpy as np

from vispeech.motion.track import Track

ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
)
"""The 52 ARKit face blend shapes (Apple's order; key by name, never by position)."""

TONGUE_CHANNELS: tuple[str, ...] = ("tongueOut", "tongueTipUp", "tongueBodyUp", "tongueBack")
"""The tongue: ARKit's ``tongueOut`` and vispeech's own tip raise, body raise and backing (0..1 each;
:mod:`vispeech.postprocess.tongue` sets them, :mod:`vispeech.motion.rigging.tongue` gives a head their
morph targets)."""

MORPH_NAMES: tuple[str, ...] = ARKIT_NAMES + TONGUE_CHANNELS[1:]
"""Every channel a head's morph target can carry: the ARKit shapes and vispeech's tongue channels."""

MOUTH_CHANNELS: tuple[str, ...] = tuple(
    name for name in ARKIT_NAMES if name.startswith(("jaw", "mouth")) or name in ("cheekPuff", "tongueOut")
)
"""Jaw, lip, cheek-puff and tongue channels: what speech animation drives."""

THESIS_CHANNELS: tuple[str, ...] = (
    "jawForward",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthSmileLeft",
    "mouthDimpleLeft",
    "mouthStretchLeft",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthLowerDownLeft",
    "mouthUpperUpLeft",
    "cheekPuff",
    "cheekSquintLeft",
    "noseSneerLeft",
)
"""The thesis's 18 output channels, in its order (Left kept of each pair)."""

ARTICULATORY_CHANNELS: tuple[str, ...] = ("jaw_opening", "lip_aperture", "lip_width", "protrusion")
"""Beskow-style articulatory parameters (not ARKit shapes), in eye-corner distances; measured on
face landmarks by :func:`vispeech.corpus.articulation.articulatory_parameters`."""


LIP_CLOSED = 0.05
"""Lip aperture (see :func:`lip_aperture`) at or below which the lips count as closed."""

_APERTURE_TERMS: tuple[tuple[str, float], ...] = (
    ("jawOpen", 1.0),
    ("mouthClose", -1.0),
    ("mouthLowerDownLeft", 0.25),
    ("mouthLowerDownRight", 0.25),
    ("mouthUpperUpLeft", 0.15),
    ("mouthUpperUpRight", 0.15),
    ("mouthFunnel", 0.1),
    ("mouthRollLower", -0.5),
    ("mouthRollUpper", -0.3),
    ("mouthPressLeft", -0.1),
    ("mouthPressRight", -0.1),
)


def lip_aperture(track: Track) -> np.ndarray:
    """Approximate vertical inner-lip opening per frame, on a 0..1 scale.

    ``jawOpen − mouthClose + 0.5·lowerDown + 0.3·upperUp + 0.1·mouthFunnel
    − 0.5·mouthRollLower − 0.3·mouthRollUpper − 0.2·press``, clipped to [0, 1], where
    ``lowerDown``, ``upperUp`` and ``press`` are the means of their Left/Right channels.
    ARKit's ``mouthClose`` closes the lips against ``jawOpen``; lowering the lower lip or
    raising the upper one opens them; rolling the lips in or pressing them closes them.
    Channels the track lacks count as 0. Frames at or below :data:`LIP_CLOSED` are closed.
    """
    aperture = np.zeros(track.n_frames)
    for channel, weight in _APERTURE_TERMS:
        if channel in track.channels:
            aperture += weight * track[channel]
    return np.clip(aperture, 0.0, 1.0)
