"""A pretrained speech encoder (wav2vec 2.0, WavLM, HuBERT; Whisper in
:mod:`vispeech.frontends.whisper`) as an audio front end.

The model comes from a local folder the user gives (a ``transformers`` model folder: a
``config.json``, its weights and, usually, a ``preprocessor_config.json``), loaded with
``local_files_only=True``: vispeech never downloads one. It needs the ``encoder`` extra
(``transformers`` and torch); everything here imports them only when a model is loaded.

Framing: the encoders' convolutional front end reads 25 ms of 16 kHz audio every 20 ms, so
hidden-state frame j covers ``[20 j, 20 j + 25)`` ms: it is frame j of a 50 fps track and looks
25 ms past its own time. :meth:`SpeechEncoder.hidden_states` returns every hidden state (the
front end's projected output, then each transformer layer's) for ``clip.n_frames(50)`` frames,
i.e. ``ceil(duration · 50)`` (the last frame repeated where the encoder's run out). The waveform
is normalised to zero mean and unit variance over the whole clip when the feature extractor
config says ``do_normalize`` (without one: when the model's ``feat_extract_norm`` is
``"layer"``, as the large checkpoints want). Long audio is encoded in chunks of
:data:`CHUNK_SECONDS`, each with :data:`CHUNK_OVERLAP` seconds of audio either side that is
encoded for context and dropped, so attention memory stays bounded (10 minutes of audio are
20 chunks); a chunk's frames differ slightly from one whole-clip pass (attention and the
front end's group norm see the chunk only).
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip

if TYPE_CHECKING:
    from vispeech.frontends.whisper import WhisperEncoder

FRAME_RATE = 50.0
"""Hidden-state frames per second (the encoders' 20 ms stride)."""
MODEL_TYPES = ("wav2vec2", "wavlm", "hubert")
"""The ``model_type`` values of ``config.json`` that vispeech reads."""
CHUNK_SECONDS = 30.0
"""Audio encoded per chunk (seconds)."""
CHUNK_OVERLAP = 2.0
"""Audio (seconds) encoded either side of a chunk for context, then dropped."""
INSTALL = 'pip install "vispeech[encoder]"'


class SpeechEncoder:
    """A loaded speech encoder: :attr:`layers` hidden states of :attr:`width` values per frame."""

    def __init__(self, folder: str, model: Any, sample_rate: int, normalize: bool) -> None:
        self.folder = folder
        self.model = model
        self.sample_rate = sample_rate
        """Hz: the rate the model reads."""
        self.normalize = normalize
        """Whether the waveform is standardised first."""
        config = model.config
        self.layers = int(config.num_hidden_layers) + 1
        """Hidden states per frame: the front end's output and one per transformer layer."""
        self.width = int(config.hidden_size)
        """Values per hidden state."""
        self.stride = math.prod(config.conv_stride)
        """Samples between frames."""
        self.receptive = 1 + sum((k - 1) * math.prod(config.conv_stride[:i]) for i, k in enumerate(config.conv_kernel))
        """Samples one frame reads."""

    @classmethod
    def load(cls, folder: str | Path, depth: int = 0) -> SpeechEncoder | WhisperEncoder:
        """The encoder in ``folder`` (loaded once per folder, then shared): a transformers folder,
        or Whisper (a name of :data:`vispeech.frontends.whisper.MODELS` or a CTranslate2 folder
        with ``model.bin``; :class:`vispeech.frontends.whisper.WhisperEncoder`), whose states
        after its first ``depth`` transformer layers are read (0: all; Whisper only)."""
        path = Path(folder).expanduser()
        if str(folder).startswith("whisper-") or (path / "model.bin").is_file():
            from vispeech.frontends.whisper import WhisperEncoder

            return WhisperEncoder.load(folder, depth)
        if depth:
            raise VispeechError(f"encoder_depth applies to Whisper encoders; {folder} gives all its layers' states")
        if not path.is_dir():
            raise VispeechError(f"speech encoder folder not found: {folder}")
        return _load(str(path.resolve()))

    def hidden_states(
        self, clip: AudioClip, chunk: float = CHUNK_SECONDS, overlap: float = CHUNK_OVERLAP
    ) -> np.ndarray:
        """``(layers, clip.n_frames(50), width)`` float32 hidden states of ``clip`` at 50 fps,
        encoded ``chunk`` seconds at a time with ``overlap`` seconds of context either side."""
        import torch

        samples = clip.resampled(self.sample_rate).samples.astype(np.float32)
        if self.normalize:
            samples = (samples - samples.mean()) / np.sqrt(samples.var() + 1e-7)
        n_frames = clip.n_frames(FRAME_RATE)
        per_chunk, context = max(1, round(chunk * FRAME_RATE)), round(overlap * FRAME_RATE)
        out = np.empty((self.layers, n_frames, self.width), dtype=np.float32)
        with torch.inference_mode():
            for start in range(0, n_frames, per_chunk):
                stop = min(n_frames, start + per_chunk)
                first, last = max(0, start - context), min(n_frames, stop + context)
                piece = samples[first * self.stride : (last - 1) * self.stride + self.receptive]
                piece = np.pad(piece, (0, max(0, self.receptive - len(piece))))
                states = self.model(torch.from_numpy(piece)[None], output_hidden_states=True).hidden_states
                frames = torch.stack(states)[:, 0].numpy()  # layers, frames of the piece, width
                index = np.minimum(np.arange(start - first, stop - first), frames.shape[1] - 1)
                out[:, start:stop] = frames[:, index]
        return out


@functools.cache
def _load(folder: str) -> SpeechEncoder:
    config_file = Path(folder) / "config.json"
    if not config_file.is_file():
        raise VispeechError(f"speech encoder folder {folder} has no config.json (a transformers model folder)")
    try:
        config = json.loads(config_file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise VispeechError(f"cannot read {config_file}: {exc}") from None
    model_type = config.get("model_type") if isinstance(config, dict) else None
    if model_type not in MODEL_TYPES:
        raise VispeechError(
            f"speech encoder {folder} is a {model_type!r} model; vispeech reads {', '.join(MODEL_TYPES)}"
        )
    extractor_file = Path(folder) / "preprocessor_config.json"
    extractor = json.loads(extractor_file.read_text(encoding="utf-8")) if extractor_file.is_file() else {}
    try:
        from transformers import AutoModel
    except ImportError:
        raise VispeechError(f"the speech encoder needs transformers and torch: {INSTALL}") from None
    try:
        model = AutoModel.from_pretrained(folder, local_files_only=True)
    except (OSError, ValueError) as exc:
        raise VispeechError(f"cannot load speech encoder {folder}: {str(exc).splitlines()[0]}") from None
    model.eval()
    normalize = bool(extractor.get("do_normalize", config.get("feat_extract_norm") == "layer"))
    encoder = SpeechEncoder(folder, model, int(extractor.get("sampling_rate", 16_000)), normalize)
    if encoder.sample_rate / encoder.stride != FRAME_RATE:
        raise VispeechError(
            f"speech encoder {folder} gives {encoder.sample_rate / encoder.stride:g} frames/s; "
            f"vispeech needs {FRAME_RATE:g}"
        )
    return encoder
