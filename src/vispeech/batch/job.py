"""Batch jobs: a manifest (CSV with a header, or JSONL) or a folder of inputs, read into lines.

A line animates one of three inputs, as the single-utterance commands do:

- ``text`` (+ ``language``, ``rate``): espeak-ng speech, as ``vispeech say``;
- ``audio`` (+ ``text``, its transcript, and ``language``): recorded speech, as ``vispeech animate``;
- ``alignment`` (+ ``language``, else guessed from the symbols): a phone alignment, as
  ``vispeech animate-phones``.

Every line may also set ``id`` (the name of its output folder; default its line number),
``model``, ``fps``, ``formats`` (names of :data:`vispeech.pipeline.OUTPUT_FILES`, in CSV
separated by spaces, commas or semicolons, in JSON a list or such a string) and
``postprocessing`` (``auto``, ``none`` or a preset: :data:`vispeech.postprocess.Postprocessing`);
what a line leaves out comes from the job's defaults. Paths are
relative to the manifest's folder. In CSV an empty cell is a field left out.

A folder job takes each file by its extension: ``.txt`` is a text to speak, unless an audio
file of the same stem is there (``take.wav`` + ``take.txt``): then it is that audio's
transcript; audio files (``.wav .flac .mp3 .ogg .opus .aiff``) are recordings; ``.TextGrid``,
``.lab``, ``.align`` and ``.json`` are alignments. Other files and hidden ones are passed over.

A line that cannot run (a missing input, a bad value, an id used before) is kept with its
``error`` and reported, never stopping the others; only a job that cannot be read at all (no
such manifest, no header, an unknown column) raises :class:`VispeechError`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.files import read_text
from vispeech.frontends.espeak import MAX_RATE, MIN_RATE, check_voice, find_language
from vispeech.limits import check_fps, check_text, parse_json
from vispeech.phonetics.inventory import get_inventory
from vispeech.pipeline import AUDIO_OUTPUTS, DEFAULT_FPS, DEFAULT_OUTPUTS, DEFAULT_SCALE, OUTPUT_FILES, check_formats
from vispeech.postprocess import AUTO, check_postprocessing

FIELDS = ("id", "text", "language", "audio", "alignment", "model", "fps", "rate", "formats", "postprocessing", "voice")
"""The fields a manifest line may have."""
AUDIO_SUFFIXES = (".wav", ".flac", ".mp3", ".ogg", ".oga", ".opus", ".aiff", ".aif")
"""Extensions a folder job reads as recordings."""
ALIGNMENT_SUFFIXES = (".textgrid", ".lab", ".align", ".json")
"""Extensions a folder job reads as phone alignments (compared in lower case)."""
MAX_LINES = 1_000_000
"""The most lines one job may have."""

_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


@dataclass(frozen=True)
class JobDefaults:
    """What a line that does not say gets: language, model (``None``: the pipeline's default
    for its input), frame rate, output formats and post-processing."""

    language: str = "en"
    model: str | None = None
    fps: float = DEFAULT_FPS
    formats: tuple[str, ...] = DEFAULT_OUTPUTS
    postprocessing: str = AUTO
    scale: str = DEFAULT_SCALE
    """The output scale of every line (:func:`vispeech.motion.rigging.calibration.load_scale`)."""
    voice: str | None = None
    """The voice text lines are spoken with (:func:`vispeech.frontends.espeak.voices`; ``None``: each
    language's own)."""
    life: tuple[str, ...] = ()
    """The non-verbal layers every line gets (:mod:`vispeech.motion.life`), and their seed."""
    seed: int = 0
    check_transcripts: bool = True
    """Whether an English audio line's transcript must fit its audio
    (:func:`~vispeech.frontends.align.transcript_fit`, at least
    :data:`~vispeech.frontends.align.MIN_FIT`, as ``vispeech animate`` asks); ``False`` takes
    every transcript as what its audio says, as ``vispeech animate --force`` does."""


@dataclass(frozen=True)
class BatchLine:
    """One line of a job: what to animate (``kind``: text, audio or alignment) and how.

    ``number`` is its 1-based place in the job (the manifest's data line, or the folder entry
    in name order); ``error`` says why the line cannot run, ``None`` when it can. ``language`` is
    ``None`` for an alignment whose language is guessed from its symbols.
    """

    number: int
    id: str
    kind: str = "text"
    text: str | None = None
    language: str | None = "en"
    audio: Path | None = None
    alignment: Path | None = None
    model: str | None = None
    fps: float = DEFAULT_FPS
    rate: float = 1.0
    formats: tuple[str, ...] = DEFAULT_OUTPUTS
    postprocessing: str = AUTO
    scale: str = DEFAULT_SCALE
    voice: str | None = None
    life: tuple[str, ...] = ()
    seed: int = 0
    check_transcript: bool = True
    error: str | None = field(default=None, compare=False)

    @property
    def source(self) -> Path | None:
        """The input file (audio or alignment), ``None`` for a text."""
        return self.audio if self.kind == "audio" else self.alignment


def read_job(path: str | os.PathLike, defaults: JobDefaults = JobDefaults()) -> list[BatchLine]:
    """The lines of the job at ``path``: a folder of inputs, a ``.csv`` or a ``.jsonl`` manifest.

    Ids are checked to be unique (a repeat is an error of that line). Raises
    :class:`VispeechError` when the job cannot be read at all.
    """
    path = Path(path)
    if path.is_dir():
        lines = _folder_lines(path, defaults)
    elif not path.exists():
        raise VispeechError(f"batch job {path} not found")
    else:
        suffix = path.suffix.lower()
        if suffix == ".csv":
            records = _csv_records(read_text(path, "batch manifest"), path)
        elif suffix in (".jsonl", ".ndjson"):
            records = _jsonl_records(read_text(path, "batch manifest"), path)
        else:
            raise VispeechError(f"batch job {path}: give a folder, a .csv or a .jsonl manifest")
        lines = [_parse_line(number, record, path.parent, defaults) for number, record in records]
    if len(lines) > MAX_LINES:
        raise VispeechError(f"batch job {path} has {len(lines)} lines; the limit is {MAX_LINES}")
    return _unique_ids(lines)


def _csv_records(text: str, path: Path) -> list[tuple[int, dict | str]]:
    reader = csv.DictReader(io.StringIO(text.lstrip("\ufeff"), newline=""))
    columns = [c.strip() for c in reader.fieldnames or []]
    if not columns:
        raise VispeechError(f"batch manifest {path} has no header line (columns: {', '.join(FIELDS)})")
    twice = next((c for c in columns if columns.count(c) > 1), None)
    if twice is not None:
        raise VispeechError(f"batch manifest {path}: column {twice!r} appears twice")
    unknown = [c for c in columns if c not in FIELDS]
    if unknown:
        raise VispeechError(f"batch manifest {path}: unknown column {unknown[0]!r} (columns: {', '.join(FIELDS)})")
    if not {"text", "audio", "alignment"} & set(columns):
        raise VispeechError(f"batch manifest {path} needs a text, audio or alignment column")
    records: list[tuple[int, dict | str]] = []
    for number, row in enumerate(reader, start=1):
        if None in row:
            records.append((number, f"has {len(columns) + len(row[None])} cells for {len(columns)} columns"))
            continue
        record = {k.strip(): v for k, v in row.items() if v is not None and v.strip() != ""}
        records.append((number, record))
    return records


def _jsonl_records(text: str, path: Path) -> list[tuple[int, dict | str]]:
    records: list[tuple[int, dict | str]] = []
    for physical, line in enumerate(text.lstrip("\ufeff").splitlines(), start=1):
        if not line.strip():
            continue
        number = len(records) + 1  # the job's line number (blank lines skipped): its default id
        try:
            record = parse_json(line, f"line {physical} of {path.name}")
        except VispeechError as exc:
            records.append((number, str(exc)))
            continue
        if not isinstance(record, dict):
            records.append((number, "is not a JSON object"))
            continue
        unknown = [k for k in record if k not in FIELDS]
        if unknown:
            records.append((number, f"has an unknown field {unknown[0]!r} (fields: {', '.join(FIELDS)})"))
            continue
        records.append((number, {k: v for k, v in record.items() if v is not None}))
    return records


def _folder_lines(folder: Path, defaults: JobDefaults) -> list[BatchLine]:
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    audio_stems = {p.stem for p in files if p.suffix.lower() in AUDIO_SUFFIXES}
    lines: list[BatchLine] = []
    for p in files:
        suffix = p.suffix.lower()
        record: dict = {"id": p.stem}
        try:  # a text that cannot be read is its line's error, as in a manifest
            if suffix in AUDIO_SUFFIXES:
                record["audio"] = p.name
                transcript = p.with_suffix(".txt")
                if transcript.is_file():
                    record["text"] = read_text(transcript, "transcript").strip()
            elif suffix == ".txt" and p.stem not in audio_stems:
                record["text"] = read_text(p, "text").strip()
            elif suffix in ALIGNMENT_SUFFIXES:
                record["alignment"] = p.name
            else:
                continue
        except VispeechError as exc:
            lines.append(BatchLine(len(lines) + 1, p.stem, error=str(exc)))
            continue
        lines.append(_parse_line(len(lines) + 1, record, folder, defaults))
    return lines


def _parse_line(number: int, record: dict | str, base: Path, defaults: JobDefaults) -> BatchLine:
    """A :class:`BatchLine` from one manifest record (a problem with it becomes the line's error)."""
    fallback = f"{number:05d}"
    if isinstance(record, str):
        return BatchLine(number, fallback, error=record)
    raw_id = record.get("id", fallback)
    line_id = raw_id if isinstance(raw_id, str) else str(raw_id)
    try:
        return _checked_line(number, line_id, record, base, defaults)
    except VispeechError as exc:
        return BatchLine(number, line_id, error=str(exc))


def _checked_line(number: int, line_id: str, record: dict, base: Path, defaults: JobDefaults) -> BatchLine:
    if not _ID.fullmatch(line_id):
        raise VispeechError(f"id {line_id!r} is not a folder name (letters, digits, '.', '_', '-'; at most 128)")
    text, audio, alignment = (record.get(k) for k in ("text", "audio", "alignment"))
    for key, value in (
        ("text", text),
        ("audio", audio),
        ("alignment", alignment),
        ("language", record.get("language")),
        ("model", record.get("model")),
    ):
        if value is not None and not isinstance(value, str):
            raise VispeechError(f"{key} must be a string, got {json.dumps(value)[:40]}")
    if audio is not None and alignment is not None:
        raise VispeechError("give audio or alignment, not both")
    if alignment is not None and text is not None:
        raise VispeechError("an alignment line takes no text (its phones are timed already)")
    if audio is None and alignment is None and text is None:
        raise VispeechError("the line has no text, audio or alignment")
    kind = "audio" if audio is not None else "alignment" if alignment is not None else "text"
    if text is not None:
        if not text.strip():
            raise VispeechError("text is empty")
        check_text(text)
    language = record.get("language", None if kind == "alignment" else defaults.language)
    if language is not None and kind == "alignment":
        get_inventory(language)  # the alignment's phone set
    elif language is not None:
        language = find_language(language).code
    fps = check_fps(_number(record.get("fps", defaults.fps), "fps"))
    rate = _number(record.get("rate", 1.0), "rate")
    if not MIN_RATE <= rate <= MAX_RATE:
        raise VispeechError(f"rate must be between {MIN_RATE} and {MAX_RATE}, got {rate:g}")
    if "rate" in record and kind != "text":
        raise VispeechError("rate is for text lines (espeak-ng's speaking rate)")
    if "voice" in record and kind != "text":
        raise VispeechError("voice is for text lines (the voice espeak-ng speaks them with)")
    voice = check_voice(record.get("voice", defaults.voice) or None)
    formats = record.get("formats", defaults.formats)
    if isinstance(formats, str):
        formats = [f for f in re.split(r"[\s,;]+", formats) if f]
    if not isinstance(formats, list | tuple) or not all(isinstance(f, str) for f in formats):
        raise VispeechError("formats must be a list of format names or a string of them")
    formats = check_formats(formats)
    if kind == "alignment" and set(formats) <= set(AUDIO_OUTPUTS):
        raise VispeechError(
            f"an alignment line has no audio, so none of its formats ({', '.join(formats)}) can be written: "
            f"ask for a track format ({', '.join(f for f in OUTPUT_FILES if f not in AUDIO_OUTPUTS)})"
        )
    return BatchLine(
        number=number,
        id=line_id,
        kind=kind,
        text=text,
        language=language,
        audio=None if audio is None else base / audio,
        alignment=None if alignment is None else base / alignment,
        model=record.get("model", defaults.model),
        fps=fps,
        rate=rate,
        formats=formats,
        postprocessing=_postprocessing(record.get("postprocessing", defaults.postprocessing)),
        scale=defaults.scale,
        voice=voice if kind == "text" else None,
        life=defaults.life,
        seed=defaults.seed,
        check_transcript=defaults.check_transcripts,
    )


def _number(value, what: str) -> float:
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise VispeechError(f"{what} must be a number, got {str(value)[:40]!r}")
    return number


def _postprocessing(value) -> str:
    name = value.strip() if isinstance(value, str) else str(value)
    check_postprocessing(name)
    return name


def _unique_ids(lines: list[BatchLine]) -> list[BatchLine]:
    """Lines with each id once: a later line reusing an id gets an error naming the first."""
    first: dict[str, int] = {}
    unique = []
    for line in lines:
        if line.id in first:
            line = BatchLine(line.number, line.id, error=f"id {line.id!r} is used by line {first[line.id]} already")
        elif line.error is None:
            first[line.id] = line.number
        unique.append(line)
    return unique
