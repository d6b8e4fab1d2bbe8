"""Reader for the GRID audio-visual corpus layout (one speaker) with MediaPipe face tracks, and
the face-track CSV's reader and writer (captured takes keep their tracks in it too).

Layout (see ``shared/data/grid_s1/README.md``)::

    sentences.tsv            id <TAB> text
    utterances/<id>.flac     audio
    utterances/<id>.align    word timings "<start> <end> <word>" in 1/25000 s, sil/sp for pauses
    utterances/<id>.csv      face track at its video's frame rate (GRID: 25 fps): frame, time,
                             ARKit scores, head pose, landmarks lm<K>_x/_y/_z (rows with no face
                             leave those empty)
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from vispeech.alignment.formats import read_word_alignment
from vispeech.corpus.cache import CorpusCache, content_hash
from vispeech.corpus.corpus import Corpus, Utterance, check_durations, common_frame_rate, recorded_track, report_problem
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.frontends.audio import audio_duration
from vispeech.motion.track import Track


def read_grid(
    directory: str | os.PathLike,
    *,
    strict: bool = False,
    cache: str | os.PathLike | None = None,
) -> Corpus:
    """Read a GRID folder into a :class:`Corpus` (language ``en``).

    Frames where the tracker found no face are filled in: linearly between tracked frames,
    held at the first / last tracked value at the ends; ``Utterance.frame_mask`` marks them
    False. Each track keeps the frame rate of its ``time`` column, so clips of different rates
    and lengths make one corpus (``Corpus.fps``: the most common rate). Utterances with a missing
    or unreadable file, an empty transcript, ``.align`` words that differ from the transcript, no
    tracked frame, a track whose length differs from the audio's or whose columns differ from the
    first utterance's are skipped with a :class:`~vispeech.corpus.corpus.CorpusWarning` naming
    each (listed in ``Corpus.problems``), or raise :class:`VispeechError` if ``strict``.
    ``cache`` overrides the cache folder (default: see :mod:`vispeech.corpus.cache`).
    """
    root = Path(directory)
    sentences_path = root / "sentences.tsv"
    folder = root / "utterances"
    if not sentences_path.is_file() or not folder.is_dir():
        raise VispeechError(f"{root} is not a GRID folder (needs sentences.tsv and utterances/)")
    sentences = _read_sentences(sentences_path)

    utterances: list[Utterance] = []
    problems: list[str] = []
    for utterance_id, text in sentences:
        try:
            utterance = _read_utterance(folder, utterance_id, text)
            if utterances and recorded_track(utterance).channels != recorded_track(utterances[0]).channels:
                raise VispeechError("its track's columns differ from the other utterances'")
        except VispeechError as exc:
            report_problem(problems, f"skipped {utterance_id}: {exc}", strict)
            continue
        utterances.append(utterance)

    files = [sentences_path, *(p for p in folder.iterdir() if p.is_file())]
    return Corpus(
        name=root.resolve().name,
        utterances=utterances,
        fps=common_frame_rate((recorded_track(u) for u in utterances), 25.0),
        channels=recorded_track(utterances[0]).channels if utterances else (),
        language="en",
        root=root,
        problems=problems,
        cache=CorpusCache.for_corpus(root.resolve().name, content_hash(files, root), cache),
    )


def _read_sentences(path: Path) -> list[tuple[str, str]]:
    rows = []
    lines = path.read_text(encoding="utf-8").splitlines()
    for number, line in enumerate(lines, start=1):
        if not line.strip() or (number == 1 and line.split("\t")[0] == "id"):
            continue
        utterance_id, _, text = line.partition("\t")
        rows.append((utterance_id.strip(), " ".join(text.split())))
    return rows


def _read_utterance(folder: Path, utterance_id: str, text: str) -> Utterance:
    if not text:
        raise VispeechError("empty transcript")
    paths = {ext: folder / f"{utterance_id}.{ext}" for ext in ("flac", "align", "csv")}
    absent = [p.name for p in paths.values() if not p.is_file()]
    if absent:
        raise VispeechError(f"missing {', '.join(absent)}")
    words = read_word_alignment(paths["align"])
    if [w.text for w in words] != text.split():
        raise VispeechError(f".align words {' '.join(w.text for w in words)!r} differ from the transcript {text!r}")
    track, landmarks, mask = read_face_csv(paths["csv"])
    duration = audio_duration(paths["flac"])
    check_durations(track, duration)
    return Utterance(
        id=utterance_id,
        text=text,
        audio_path=paths["flac"],
        duration=duration,
        track=track,
        words=words,
        landmarks=landmarks,
        frame_mask=mask,
    )


def read_face_csv(path: str | os.PathLike) -> tuple[Track, dict[str, np.ndarray], np.ndarray]:
    """Read a GRID face-track CSV: ``(track, landmarks, frame_mask)``.

    The track holds every column but ``frame``, ``time`` and the landmarks, at the frame rate
    of its rows over the ``time`` column's span (to 0.001 fps: the column's 4 decimals would
    make 30 fps 30.03 step by step); ``landmarks["lm<K>"]`` is ``(n_frames, 3)``. Rows with empty
    fields are untracked frames: filled as :func:`fill_missing_frames` does, False in the mask.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise VispeechError(f"unreadable {path.name}: {exc}") from None
    if len(lines) < 3:
        raise VispeechError(f"{path.name} has fewer than two frames")
    header = lines[0].split(",")
    if header[:2] != ["frame", "time"]:
        raise VispeechError(f"{path.name} does not start with columns frame,time")
    n_columns = len(header)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        fields = line.split(",")
        if len(fields) == 2:  # an untracked frame: only frame and time
            fields += [""] * (n_columns - 2)
        if len(fields) != n_columns:
            raise VispeechError(f"{path.name} line {number} has {len(fields)} fields, expected {n_columns}")
        rows.append(",".join(f if f else "nan" for f in fields))
    try:
        data = np.loadtxt(io.StringIO("\n".join(rows)), delimiter=",", ndmin=2)
    except ValueError as exc:
        raise VispeechError(f"unreadable {path.name}: {exc}") from None

    times = data[:, 1]
    steps = np.diff(times)
    if not np.all(np.isfinite(times)) or np.any(steps <= 0):
        raise VispeechError(f"{path.name}: the time column is not increasing")
    fps = round((len(times) - 1) / float(times[-1] - times[0]), 3)  # rows over the span: times carry 4 decimals
    values, mask = fill_missing_frames(data[:, 2:])
    if not mask.any():
        raise VispeechError(f"{path.name}: no face tracked in any frame")

    names = header[2:]
    channel_idx = [j for j, name in enumerate(names) if not name.startswith("lm")]
    landmarks = {}
    for j, name in enumerate(names):
        if name.startswith("lm") and name.endswith("_x"):
            key = name[:-2]
            try:
                cols = [j, names.index(f"{key}_y"), names.index(f"{key}_z")]
            except ValueError:
                raise VispeechError(f"{path.name}: landmark {key} lacks its _y or _z column") from None
            landmarks[key] = values[:, cols]
    track = Track(values[:, channel_idx], tuple(names[j] for j in channel_idx), fps, float(times[0]))
    return track, landmarks, mask


def write_face_csv(
    path: str | os.PathLike,
    values: np.ndarray,
    channels: Sequence[str],
    landmarks: Mapping[str, np.ndarray],
    fps: float,
) -> None:
    """Write a face track in GRID's layout (what :func:`read_face_csv` reads): ``frame``, ``time``
    (frame / ``fps``), the ``channels`` of ``values`` (frames × channels), then ``<name>_x``,
    ``_y``, ``_z`` of each landmark (frames × 3). A frame with any NaN is untracked: its row holds
    ``frame`` and ``time`` and empty fields. Written atomically."""
    header = ["frame", "time", *channels, *(f"{name}_{axis}" for name in landmarks for axis in "xyz")]
    data = np.concatenate([np.asarray(values, float), *(np.asarray(v, float) for v in landmarks.values())], axis=1)
    lines = [",".join(header)]
    empty = "," * (len(header) - 3)
    for k, row in enumerate(data):
        fields = f"{k},{k / fps:.4f}"
        lines.append(fields + "," + (",".join(f"{v:.6g}" for v in row) if np.isfinite(row).all() else empty))
    with atomic_output_file(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


def fill_missing_frames(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill frames (rows) holding any NaN: ``(filled values, mask of complete rows)``.

    Each column is interpolated linearly between the nearest complete frames and held
    constant before the first and after the last one. With no complete frame the values are
    returned as they are.
    """
    values = np.asarray(values, dtype=float)
    mask = np.all(np.isfinite(values), axis=1)
    if mask.all() or not mask.any():
        return values, mask
    frames = np.arange(len(values))
    filled = values.copy()
    for j in range(values.shape[1]):
        filled[~mask, j] = np.interp(frames[~mask], frames[mask], values[mask, j])
    return filled, mask
