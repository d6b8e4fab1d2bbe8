"""Voice activity of live audio: Silero VAD v6, window by window, and the speech spans it shows.

Silero VAD (MIT, Silero Team; ``data/silero_vad_v6.onnx``, the file faster-whisper 1.2.1 ships)
runs under ONNX Runtime (the ``serve`` and ``whisper`` extras) on windows of :data:`WINDOW`
samples at 16 kHz (32 ms), each with the :data:`CONTEXT` samples before it, carrying its LSTM's
state from window to window: fed in pieces of any size it gives exactly what it gives on the
whole audio at once (tested). A window is speech from the first whose probability reaches
:data:`THRESHOLD` until one falls below :data:`RELEASE` (hysteresis, as faster-whisper's
``get_speech_timestamps``), so a soft syllable inside a word does not end the speech, and
speech resuming within :data:`MIN_SILENCE` continues its span.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vispeech.errors import VispeechError

if TYPE_CHECKING:
    import onnxruntime

SAMPLE_RATE = 16_000
"""Hz of the audio the detector takes."""
WINDOW = 512
"""Samples a probability is computed on (32 ms)."""
CONTEXT = 64
"""Samples of the window before that each window is given with."""
THRESHOLD = 0.5
"""Probability at which speech starts."""
RELEASE = 0.35
"""Probability below which speech ends."""
MIN_SILENCE = 0.1
"""Seconds of silence that part two spans of speech (Silero's ``min_silence_duration_ms``)."""
MODEL = Path(__file__).parent / "data" / "silero_vad_v6.onnx"


def installed() -> bool:
    """Whether ONNX Runtime is installed, which :class:`VoiceActivity` runs on."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


@functools.lru_cache(maxsize=1)
def _session() -> onnxruntime.InferenceSession:
    """The ONNX Runtime session of the model, one thread, shared by every detector of the process."""
    try:
        import onnxruntime
    except ImportError:
        raise VispeechError("voice activity detection needs ONNX Runtime: pip install 'vispeech[serve]'") from None
    options = onnxruntime.SessionOptions()
    options.inter_op_num_threads = options.intra_op_num_threads = 1
    options.log_severity_level = 4
    return onnxruntime.InferenceSession(str(MODEL), sess_options=options, providers=["CPUExecutionProvider"])


class VoiceActivity:
    """Speech probabilities and spans of one live audio stream.

    :meth:`push` takes the next samples (float32 at :data:`SAMPLE_RATE`, any number) and returns
    the probabilities of the windows they completed; :attr:`spans` holds the speech found so far,
    ``(n, 2)`` start and end seconds, the last one ending at the latest window while speech goes on.
    """

    def __init__(self) -> None:
        self._session = _session()
        self._state = np.zeros((2, 1, 1, 128), dtype=np.float32)
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
        audio = np.concatenate([self._pending, np.asarray(samples, dtype=np.float32)])
        n = len(audio) // WINDOW
        self._pending = audio[n * WINDOW :]
        if not n:
            return np.zeros(0, dtype=np.float32)
        frames = audio[: n * WINDOW].reshape(n, WINDOW)
        before = np.concatenate([self._context[None], frames[:-1, -CONTEXT:]])
        self._context = frames[-1, -CONTEXT:].copy()
        h, c = self._state
        probabilities, h, c = self._session.run(None, {"input": np.hstack([before, frames]), "h": h, "c": c})
        self._state = np.stack([h, c])
        probabilities = np.asarray(probabilities, dtype=np.float32).reshape(n)
        for p in probabilities.tolist():
            self._step(p)
        return probabilities

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
