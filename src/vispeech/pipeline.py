"""One utterance end to end: text or phones → control model → post-processing → output files.

The CLI (``say``, ``animate-phones``) and the server are thin layers over these calls.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from scipy.io import wavfile

from vispeech.alignment.formats import write_textgrid
from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir
from vispeech.models.contract import ControlModel
from vispeech.models.registry import load_model
from vispeech.motion.io import write_track
from vispeech.motion.track import Track
from vispeech.postprocess import PostprocessConfig, SoftCeiling, postprocess

DEFAULT_FPS = 30.0
DEFAULT_MODEL = "grid-tdnn"
"""The shipped network trained on GRID (``vispeech/models/pretrained``), for every language."""
GREETINGS = {
    "sv": "Hej! Hur kan jag hjälpa dig idag?",
    "en": "Hello, how can I help you today?",
}
"""What ``vispeech say`` speaks when given no text."""


@dataclass
class Utterance:
    """A synthesised or aligned utterance: phones, animation and (when synthesised) audio."""

    phones: PhoneSequence
    track: Track
    text: str | None = None
    audio: np.ndarray | None = None
    sample_rate: int | None = None

    def wav_bytes(self) -> bytes | None:
        """The audio as a 16-bit PCM WAV file in memory (``None`` without audio)."""
        if self.audio is None:
            return None
        buffer = io.BytesIO()
        pcm = np.clip(np.asarray(self.audio) * 32767.0, -32768, 32767).astype(np.int16)
        wavfile.write(buffer, int(self.sample_rate), pcm)
        return buffer.getvalue()


def animate(
    phones: PhoneSequence,
    model: str | ControlModel = DEFAULT_MODEL,
    fps: float = DEFAULT_FPS,
    postprocessing: PostprocessConfig | bool = True,
) -> Track:
    """Animation for a time-aligned phone sequence at ``fps`` frames per second.

    ``model`` is a model name (see :data:`vispeech.models.registry.MODEL_NAMES`), a saved
    model folder or a model object; ``postprocessing`` is a configuration, ``True`` for the
    one the model recommends (:func:`postprocess_config`) or ``False`` for none.
    """
    phones.validate()
    estimator = model if isinstance(model, ControlModel) else load_model(model)
    track = estimator.predict(phones, fps)
    if postprocessing is False:
        return track
    config = postprocessing if isinstance(postprocessing, PostprocessConfig) else postprocess_config(estimator)
    return postprocess(track, phones, config)


def postprocess_config(model: ControlModel) -> PostprocessConfig:
    """The post-processing ``model`` recommends: its :attr:`~ControlModel.postprocessing` entry
    (fields of :class:`PostprocessConfig`, ceilings as ``{channel: {"threshold", "maximum",
    "input_max"}}``) over the defaults, or the defaults when it has none."""
    recommended = model.postprocessing
    if recommended is None:
        return PostprocessConfig()
    known = {f.name for f in fields(PostprocessConfig)}
    unknown = sorted(set(recommended) - known)
    if unknown:
        raise VispeechError(f"model {model.name} recommends unknown post-processing settings: {', '.join(unknown)}")
    settings = dict(recommended)
    try:
        if "ceilings" in settings:
            settings["ceilings"] = {channel: SoftCeiling(**ceiling) for channel, ceiling in settings["ceilings"].items()}
        return PostprocessConfig(**settings)
    except (TypeError, AttributeError) as exc:
        raise VispeechError(f"model {model.name} recommends bad post-processing settings: {exc}") from None


def speak(
    text: str,
    language: str = "en",
    *,
    model: str | ControlModel = DEFAULT_MODEL,
    rate: float = 1.0,
    fps: float = DEFAULT_FPS,
    postprocessing: PostprocessConfig | bool = True,
) -> Utterance:
    """Synthesise ``text`` with espeak-ng and animate it: audio, phones and a track of equal length."""
    from vispeech.frontends.espeak import synthesize

    speech = synthesize(text, language, rate=rate)
    track = animate(speech.phones, model, fps, postprocessing)
    return Utterance(speech.phones, track, text, speech.audio, speech.sample_rate)


def write_outputs(utterance: Utterance, out_dir: str | Path, *, title: str | None = None) -> list[Path]:
    """Write an utterance's files into ``out_dir`` atomically and return their paths.

    Always ``animation.csv`` (Live Link Face) and ``animation.json``; with audio also
    ``speech.wav``, ``phones.TextGrid`` and ``preview.html``.
    """
    from vispeech.preview import render_preview

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise VispeechError(f"output path {out_dir} exists and is not a folder")
    names: list[str] = []
    with atomic_output_dir(out_dir) as staging:
        wav = utterance.wav_bytes()
        if wav is not None:
            (staging / "speech.wav").write_bytes(wav)
            names.append("speech.wav")
            write_textgrid(utterance.phones, staging / "phones.TextGrid")
            names.append("phones.TextGrid")
        write_track(utterance.track, staging / "animation.csv", "livelink")
        write_track(utterance.track, staging / "animation.json", "json", phones=utterance.phones)
        names += ["animation.csv", "animation.json"]
        if wav is not None:
            html = render_preview(utterance.track, utterance.phones, wav, title or utterance.text or "vispeech")
            (staging / "preview.html").write_text(html, encoding="utf-8")
            names.append("preview.html")
    return [out_dir / n for n in names]
