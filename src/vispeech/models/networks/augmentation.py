"""Training utterances as other voices would have said them: the audio networks' augmentation.

Each copy of a training utterance (:func:`augmented_copy`) goes through a random chain of
:mod:`vispeech.frontends.effects`, drawn to cover what users send:

- always another **voice**: pitch moved by up to ±:data:`PITCH` semitones and the formants (the
  vocal tract's length) scaled by a factor within :data:`FORMANTS`, independently, so a male
  voice becomes a higher or lower, shorter- or longer-tracted one;
- with probability :data:`P_SPEED`, another **speaking rate** within :data:`SPEED`, the face
  track, phones and words time-warped alike (a faster talker moves the jaw faster);
- with probability :data:`P_ROOM`, a **room** (RT60 0.2-0.8 s, 20-60 % reverberant);
- with probability :data:`P_NOISE`, **noise** at 5-30 dB SNR, white to brown;
- then at most one **channel**: a telephone line (:data:`P_TELEPHONE`) or a lossy codec at low
  to middle quality (:data:`P_CODEC`).

The copy's audio is held in memory (``audio``, ``sample_rate``); its ``id`` is the original's
with ``~k``. The draws are seeded by the network's seed and the utterance's id, so a fit is
repeatable (up to the faint dither of Praat's resynthesis).
"""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np

from vispeech.frontends import effects
from vispeech.motion.track import Track

PITCH = 5.0
"""Semitones the pitch moves by at most, either way."""
FORMANTS = (0.85, 1.2)
"""Range of the formant (vocal-tract length) factor."""
SPEED = (0.8, 1.3)
"""Range of the speaking-rate factor."""
P_SPEED, P_ROOM, P_NOISE, P_TELEPHONE, P_CODEC = 0.5, 0.3, 0.3, 0.1, 0.2
"""Probabilities of each effect in a copy."""


def augmented_copy(utterance, index: int, seed: int = 0):
    """Copy ``index`` (1, 2, ...) of a training utterance with audio and a track, as another
    voice in another place might have said it (see the module docstring)."""
    rng = np.random.default_rng([seed, index, zlib.crc32(str(getattr(utterance, "id", "")).encode())])
    samples, rate = utterance.load_audio()
    x = effects.shift_voice(samples, rate, float(rng.uniform(-PITCH, PITCH)), float(rng.uniform(*FORMANTS)))
    track, phones, words = utterance.track, utterance.phones, utterance.words
    if rng.random() < P_SPEED:
        speed = float(rng.uniform(*SPEED))
        x = effects.time_stretch(x, speed)
        n_frames = max(1, int(np.ceil(track.n_frames / speed)))
        track = Track(track.values, track.channels, track.fps * speed, track.start_time / speed).resample(
            track.fps, n_frames=n_frames
        )
        phones = phones.scaled(1 / speed) if phones is not None else None
        words = [replace(w, start=w.start / speed, end=w.end / speed) for w in words]
    if rng.random() < P_ROOM:
        x = effects.reverberate(x, rate, float(rng.uniform(0.2, 0.8)), float(rng.uniform(0.2, 0.6)), rng)
    if rng.random() < P_NOISE:
        x = effects.add_noise(x, float(rng.uniform(5, 30)), rng, float(rng.uniform(0, 2)))
    channel = rng.random()
    if channel < P_TELEPHONE:
        x = effects.telephone(x, rate)
    elif channel < P_TELEPHONE + P_CODEC:
        x = effects.lossy(x, rate, str(rng.choice(effects.CODECS)), float(rng.uniform(0.0, 0.5)))
    return replace(
        utterance,
        id=f"{getattr(utterance, 'id', '')}~{index}",
        audio=x,
        sample_rate=rate,
        audio_path=None,
        duration=len(x) / rate,
        track=track,
        phones=phones,
        words=words,
        landmarks=None,
        frame_mask=None,
    )
