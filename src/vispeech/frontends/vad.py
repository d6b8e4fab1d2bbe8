"""Voice activity of live audio: Silero VAD v6, window by window, and the speech spans it shows.

Silero VAD (MIT, Silero Team; ``data/silero_vad_v6.onnx``, the file faster-whisper 1.2.1 ships,
run on NumPy by :mod:`vispeech.frontends.silero`) takes windows of :data:`WINDOW` samples at
16 kHz (32 ms), each with the :data:`CONTEXT` samples before it, carrying its LSTM's state from
window to window: fed in pieces of any size it gives what it gives on the whole audio at once
(to float32 rounding, tested), and :meth:`VoiceActivity.push_together` runs the windows of many
detectors in one call. A window is speech from the first whose probability reaches
:data:`THRESHOLD` until one falls below :data:`RELEASE` (hysteresis, as faster-whisper's
``get_speech_timestamps``), so a soft syllable inside a word does not end the speech, and
speech resuming within :data:`MIN_SILENCE` continues its span.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vispeech.frontends import silero

SAMPLE_RATE = 16_000
"""Hz of the audio the detector takes."""
WINDOW = 512
"""Samples a probability is computed on (32 ms)."""
CONTEXT = silero.INPUT - WINDOW
"""Samples of the window before that each window is given with (64)."""
THRESHOLD = 0.5
"""Probability at which speech starts."""
RELEASE = 0.35
"""Probability below which speech ends."""
MIN_SILENCE = 0.1
"""Seconds of silence that part two spans of speech (Silero's ``min_silence_duration_ms``)."""


class VoiceActivity:
    """Speech probabilities and spans of one live audio stream.

    :meth:`push` takes the next samples (float32 at :data:`SAMPLE_RATE`, any number) and returns
    the probabilities of the windows they completed; :attr:`spans` holds the speech found so far,
    ``(n, 2)`` start and end seconds, the last one ending at the latest window while speech goes on.
    """

    def __init__(self) -> None:
        self._state = np.zeros((2, silero.HIDDEN), dtype=np.float32)
        self._pending = np.zeros(0, dtype=np.float32)
        self._context = np.zeros(CONTEXT, dtype=np.float32)
        self.windows = 0
        """Windows seen so far."""
        self.speaking = False
        """Whether the latest window is speech."""
        self._spans: list[list[float]] = []

    @property
    def heard(self) -> float:
        """Seconds of audio the probabilities cover."""
        return self.windows * WINDOW / SAMPLE_RATE

    @property
    def spans(self) -> np.ndarray:
        """The speech so far: ``(n, 2)`` start and end seconds."""
        return np.array(self._spans, dtype=float).reshape(-1, 2)

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Probabilities (0–1) of the windows that ``samples`` completed, in order."""
        return self.push_together([self], [samples])[0]

    @staticmethod
    def push_together(detectors: Sequence[VoiceActivity], chunks: Sequence[np.ndarray]) -> list[np.ndarray]:
        """:meth:`push` of ``chunks[i]`` to ``detectors[i]``, the windows of all of them in one call of the network."""
        inputs = [detector._windows(samples) for detector, samples in zip(detectors, chunks)]
        waiting = [k for k, windows in enumerate(inputs) if len(windows)]
        out = [np.zeros(0, dtype=np.float32) for _ in detectors]
        if not waiting:
            return out
        probabilities, states = silero.network().probabilities(
            [inputs[k] for k in waiting], [detectors[k]._state for k in waiting]
        )
        for k, p, state in zip(waiting, probabilities, states):
            detectors[k]._state = state
            for probability in p.tolist():
                detectors[k]._step(probability)
            out[k] = p.astype(np.float32)
        return out

    def _windows(self, samples: np.ndarray) -> np.ndarray:
        """``(n, CONTEXT + WINDOW)``: the network inputs of the windows ``samples`` completed."""
        audio = np.concatenate([self._pending, np.asarray(samples, dtype=np.float32)])
        n = len(audio) // WINDOW
        self._pending = audio[n * WINDOW :]
        if not n:
            return np.zeros((0, CONTEXT + WINDOW), dtype=np.float32)
        frames = audio[: n * WINDOW].reshape(n, WINDOW)
        before = np.concatenate([self._context[None], frames[:-1, -CONTEXT:]])
        self._context = frames[-1, -CONTEXT:].copy()
        return np.hstack([before, frames])

    def _step(self, probability: float) -> None:
        start, end = self.heard, self.heard + WINDOW / SAMPLE_RATE
        self.windows += 1
        if self.speaking:
            self.speaking = probability >= RELEASE
        elif probability >= THRESHOLD:
            self.speaking = True
            if not self._spans or start - self._spans[-1][1] >= MIN_SILENCE:
                self._spans.append([start, end])
        if self.speaking:
            self._spans[-1][1] = end
