"""One line of a batch: its inputs prepared (the I/O and features), animated by its model and
written to its folder as one swap, and what became of it.

The local pool (:mod:`vispeech.batch.run`) runs a whole line in one process; Ray
(:mod:`vispeech.batch.cluster`) runs the halves on different workers. Both write a line's
folder with :func:`write_line`, so their outputs are the same byte for byte.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

from vispeech.batch.job import BatchLine
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.sentiment import sentiment
from vispeech.models.contract import Estimator
from vispeech.models.registry import load_model
from vispeech.motion.life import with_life
from vispeech.pipeline import (
    DEFAULT_MODEL,
    OUTPUT_FILES,
    Utterance,
    animate,
    animate_audio,
    hear,
    recording_model,
    utter,
    write_outputs,
)

RECORD = "batch.json"
"""The file in each line's folder that records its key and inputs."""

_models: dict[str, Estimator] = {}  # spec → model, per process


@dataclass(frozen=True)
class LineResult:
    """What became of one line: ``status`` is ``written``, ``unchanged`` (its outputs were up
    to date) or ``failed`` (``error`` says why); ``files`` are the names in its folder."""

    number: int
    id: str
    status: str
    key: str | None = None
    files: tuple[str, ...] = ()
    error: str | None = None
    seconds: float = 0.0


def model_spec(line: BatchLine) -> str:
    """The model a line runs: its own, else the default for its input
    (:func:`~vispeech.pipeline.recording_model` for audio, else the default phone model)."""
    if line.model is not None:
        return line.model
    return recording_model(line.text is not None, line.language or "en") if line.kind == "audio" else DEFAULT_MODEL


def loaded_model(spec: str) -> Estimator:
    """The model ``spec`` names, loaded once per process."""
    if spec not in _models:
        _models[spec] = load_model(spec)
    return _models[spec]


def expected_files(line: BatchLine) -> tuple[str, ...]:
    """The names a line's folder holds once written: its formats that its input has data for
    (audio for ``speech.wav`` and ``preview.html``, audio and phones for ``phones.TextGrid``), and the record."""
    has_audio = line.kind != "alignment"
    has_phones = line.kind != "audio" or line.text is not None
    names = [
        name
        for fmt, name in OUTPUT_FILES.items()
        if fmt in line.formats
        and (has_audio or fmt not in ("wav", "preview", "textgrid"))
        and (has_phones or fmt != "textgrid")
    ]
    return tuple(sorted([*names, RECORD]))


@dataclass
class Prepared:
    """A line's inputs made ready for its model: the utterance without its track (text, phones,
    audio) and, for a recording, its clip; the I/O and feature half of a line."""

    utterance: Utterance
    clip: AudioClip | None = None


def prepare(line: BatchLine) -> Prepared:
    """Read, synthesise or align what ``line`` animates (espeak-ng speech, a recording and its
    alignment, an alignment file)."""
    if line.kind == "text":
        assert line.text is not None  # a text line has its text (read_job)
        # language is None on a text line only from a JSON "language": null, which espeak-ng's voice
        # lookup refuses as an unknown language (VispeechError), as it did before typing
        return Prepared(utter(line.text, line.language, rate=line.rate, voice=line.voice))  # type: ignore[arg-type]
    if line.kind == "audio":
        assert line.audio is not None  # an audio line has its file (read_job)
        clip = AudioClip.read(line.audio)
        return Prepared(hear(clip, line.text, line.language or "en", force=not line.check_transcript), clip)
    from vispeech.alignment.formats import read_alignment

    assert line.alignment is not None  # the remaining kind, alignment, has its file (read_job)
    return Prepared(Utterance(phones=read_alignment(line.alignment, line.language)))


def animate_prepared(line: BatchLine, prepared: Prepared) -> Utterance:
    """The utterance of a prepared line with its track, animated by the line's model."""
    model = loaded_model(model_spec(line))
    utterance = prepared.utterance
    if prepared.clip is not None:
        track = animate_audio(prepared.clip, model, line.fps, line.postprocessing, phones=utterance.phones)
    else:
        assert utterance.phones is not None  # text and alignment lines prepare phones
        track = animate(utterance.phones, model, line.fps, line.postprocessing)
    mood = sentiment(line.text or "", line.language or "en")
    return replace(utterance, track=with_life(track, utterance.phones, line.life, line.seed, mood=mood))


def write_line(line: BatchLine, out: Path, utterance: Utterance, key: str, record: str) -> tuple[str, ...]:
    """Write a line's folder (its formats and its record) as one swap; the names written."""
    title = line.text or (line.source.name if line.source is not None else None)
    paths = write_outputs(
        utterance, out / line.id, title=title, formats=line.formats, extra={RECORD: record}, scale=line.scale
    )
    return tuple(sorted(p.name for p in paths))


def failed(line: BatchLine, key: str | None, error: BaseException | str, seconds: float = 0.0) -> LineResult:
    """The failed result of a line, with a one-line message for ``error``."""
    if isinstance(error, VispeechError):
        error = str(error)
    elif isinstance(error, OSError):
        error = f"{error.strerror or error}" + (f" ({error.filename})" if getattr(error, "filename", None) else "")
    elif isinstance(error, BaseException):
        error = f"internal error: {type(error).__name__}: {error}"
    return LineResult(line.number, line.id, "failed", key, error=error, seconds=seconds)


def run_line(line: BatchLine, out: Path, key: str, record: str) -> LineResult:
    """Prepare, animate and write one line; any error becomes the line's failed result."""
    started = time.perf_counter()
    try:
        files = write_line(line, out, animate_prepared(line, prepare(line)), key, record)
    except Exception as exc:  # noqa: BLE001 (one line's failure must not stop the batch)
        return failed(line, key, exc, time.perf_counter() - started)
    return LineResult(line.number, line.id, "written", key, files, seconds=time.perf_counter() - started)
