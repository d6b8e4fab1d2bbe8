"""Takes from talking-face video (``vispeech capture``): the corpus a camera gives.

:func:`capture_take` tracks the face in a video (:func:`vispeech.frontends.video.track_face`)
and writes a take that :func:`~vispeech.corpus.takes.read_takes` (and so ``train`` and
``evaluate``) reads, named for the video (``<name>``):

- ``<name>.wav``: the video's sound, 16 kHz mono;
- ``<name>.face.csv``: the face track in GRID's layout (:func:`~vispeech.corpus.grid.write_face_csv`):
  the 51 blend-shape scores, head pose and 19 lip, jaw and eye landmarks at the video's frame
  rate; a frame without a face is an empty row (marked, never invented);
- ``<name>.csv``: the same blend shapes and head rotation as a Live Link Face CSV, for the tools
  that read those (Unreal, Blender add-ons); frames without a face hold values interpolated
  from their neighbours there, since the format has no gaps;
- with a transcript, ``<name>.TextGrid``: words and phones by forced alignment of the sound
  (pocketsphinx for English, DTW on espeak-ng speech otherwise, :func:`vispeech.frontends.align.align`).

Every capture estimates how late the picture is against the sound
(:mod:`vispeech.corpus.av_sync`) and reports it; ``sync`` moves the face track by it, ``smooth``
filters tracker jitter (both off by default).

:func:`capture_corpus` does this for a folder of videos, each with its transcript beside it
(``<name>.txt``), into one corpus folder, in parallel. Every take is moved into its folder file
by file with its ``<name>.csv`` last (the file a take is read by), beside the takes already
there, so a rerun skips exactly the takes that are complete.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from concurrent.futures import Future, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pebble import ProcessExpired, ProcessPool

from vispeech.alignment.formats import write_textgrid
from vispeech.alignment.phones import PhoneSequence
from vispeech.corpus.articulation import lip_gap
from vispeech.corpus.av_sync import (
    MIN_OPENNESS_SECONDS,
    MIN_SECONDS,
    estimate_offset,
    openness_offset,
    shift_frames,
    smooth_frames,
)
from vispeech.corpus.grid import fill_missing_frames, write_face_csv
from vispeech.errors import VispeechError
from vispeech.frontends.align import align
from vispeech.frontends.audio import AudioClip, wav_bytes
from vispeech.frontends.video import LANDMARKS, check_installed, face_model_path, track_face, video_audio
from vispeech.motion.formats.livelink import write_livelink_csv
from vispeech.motion.track import Track

TAKE_FILES = ("{name}.wav", "{name}.face.csv", "{name}.csv", "{name}.TextGrid")
"""The files of a captured take, by the video's name."""


VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi", ".mpg", ".mpeg")
"""The files :func:`capture_corpus` takes for videos."""


@dataclass(frozen=True)
class CaptureReport:
    """What :func:`capture_take` wrote: the take's ``name``, its ``frames`` at ``fps``, the
    ``missing`` ones (no face), the sound's ``duration`` (s) and the aligned ``phones`` (0
    without a transcript)."""

    name: str
    frames: int
    missing: int
    fps: float
    duration: float
    phones: int
    offset: float
    """Seconds the picture is late against the sound (:func:`~vispeech.corpus.av_sync.estimate_offset`;
    NaN when it cannot be told), before any correction."""
    synced: bool
    """Whether the face track was moved by ``offset``."""
    timecode_offset: float | None = None
    """For a Live Link Face import: seconds into the sound at which the CSV's first row falls (NaN
    when the video has no timecode); None for a video capture."""


def capture_take(
    video: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    text: str | None = None,
    language: str = "en",
    face_model: str | os.PathLike | None = None,
    sync: bool = False,
    smooth: bool = False,
    openness: Callable[[AudioClip], np.ndarray] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> CaptureReport:
    """Write the take of ``video`` into the corpus folder ``out_dir`` (see the module docstring;
    :func:`corpus_folder`): its files replace this take's earlier ones, file by file with the
    Live Link ``<name>.csv`` (what a take is read by) last, and the other takes there stay.
    The audio–video offset is always estimated and reported: from how open a speech model
    hears the jaw in the sound where ``openness`` gives that
    (:func:`vispeech.pipeline.speech_openness`; :func:`~vispeech.corpus.av_sync.openness_offset`,
    takes of 3 s or more), else from the sound's energy (10 s or more); ``sync`` moves the face
    track by it, ``smooth`` filters tracker jitter (:mod:`vispeech.corpus.av_sync`).
    Raises :class:`VispeechError` for an unreadable video, one with no audio track or no face in
    any frame, or a transcript that cannot be aligned."""
    name = Path(video).stem
    files = [f.format(name=name) for f in TAKE_FILES]
    _check_take_folder(out_dir, files)
    check_installed()
    face_model = face_model_path(face_model)  # before any decoding
    clip = video_audio(video)
    phones = align(clip.samples, clip.sample_rate, text, language) if text is not None else None
    face = track_face(video, face_model, progress)
    found = face.found
    landmarks = {f"lm{k}": face.landmarks[:, i] for i, k in enumerate(LANDMARKS)}
    gap = lip_gap(landmarks, face.size)
    if openness is not None:
        offset, needed = openness_offset(gap, face.fps, openness(clip), mask=found), MIN_OPENNESS_SECONDS
    else:
        offset, needed = estimate_offset(gap, face.fps, clip.samples, clip.sample_rate, mask=found), MIN_SECONDS
    width = face.values.shape[1]
    frames = np.concatenate([face.values, face.landmarks.reshape(len(found), -1)], axis=1)
    if sync:
        if not np.isfinite(offset):
            raise VispeechError(
                f"{video}: cannot tell the sound's offset from the picture (it needs "
                f"{needed:g} s of speech): capture it without --sync"
            )
        frames = shift_frames(frames, offset, face.fps)
    if smooth:
        frames = smooth_frames(frames, face.fps)
    values = frames[:, :width]
    landmarks = {name: frames[:, width + 3 * i : width + 3 * i + 3] for i, name in enumerate(landmarks)}
    _write_take(out_dir, files, clip, values, face.channels, landmarks, face.fps, phones)
    missing = int((~np.isfinite(values).all(axis=1)).sum())
    return CaptureReport(name, len(values), missing, face.fps, clip.duration, _spoken(phones), offset, sync)


def _write_take(
    out_dir: str | os.PathLike,
    files: list[str],
    clip: AudioClip,
    values: np.ndarray,
    channels: tuple[str, ...],
    landmarks: dict[str, np.ndarray],
    fps: float,
    phones: PhoneSequence | None,
) -> None:
    """Write a take's files (:data:`TAKE_FILES`, named in ``files``) as one folder: the sound, the face
    track with its untracked frames (NaN rows) left empty, the Live Link CSV with them filled in
    from their neighbours (the format has no gaps), and the phones when there are some."""
    filled, _ = fill_missing_frames(values)
    out = corpus_folder(out_dir, make=True)
    with tempfile.TemporaryDirectory(prefix=".vispeech-capture-", dir=out) as staging:
        take = Path(staging)
        (take / files[0]).write_bytes(wav_bytes(clip.samples, clip.sample_rate))
        write_face_csv(take / files[1], values, channels, landmarks, fps)
        write_livelink_csv(Track(filled, channels, fps), take / files[2])  # leaves out non-Live-Link columns
        if phones is not None:
            write_textgrid(phones, take / files[3])
        # The Live Link CSV goes first and comes back last: a take is read by it (read_takes), so
        # one stopped halfway is left out with a warning, never read as files of two captures, and
        # capture_corpus captures it again.
        (out / files[2]).unlink(missing_ok=True)
        for name in sorted(files, key=lambda name: name == files[2]):
            if (take / name).is_file():
                os.replace(take / name, out / name)
            else:  # an earlier capture's phones, of another transcript
                (out / name).unlink(missing_ok=True)


def _check_take_folder(out_dir: str | os.PathLike, files: list[str]) -> None:
    """Refuse, before any work, a corpus folder (:func:`corpus_folder`) where the take's Live Link
    CSV would replace one that is no take's: a ``<name>.csv`` without the ``<name>.face.csv`` every
    capture writes beside it (the Live Link Face app names its recording as the video)."""
    out = corpus_folder(out_dir)
    if (out / files[2]).exists() and not (out / files[1]).exists():
        raise VispeechError(
            f"{out / files[2]} is no take vispeech captured (no {files[1]} beside it), and the take's own "
            "would replace it: move it away or give another -o folder"
        )


def corpus_folder(path: str | os.PathLike, make: bool = False) -> Path:
    """The corpus folder ``path`` takes are written into (``make``: made now if need be);
    :class:`VispeechError` when it is no folder or it (or, not made yet, the folder it would be
    made in) cannot be written to. Other takes' files in it stay as they are."""
    out = Path(path)
    if os.path.lexists(out) and not out.is_dir():
        raise VispeechError(f"output path {out} exists and is not a folder")
    existing = next(p for p in (out, *out.absolute().parents) if p.is_dir())
    if not os.access(existing, os.W_OK):
        raise VispeechError(f"cannot write to output folder {existing}: Permission denied")
    if make:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise VispeechError(f"cannot make output folder {out}: {exc.strerror}") from None
    return out


def _spoken(phones: PhoneSequence | None) -> int:
    """Phones other than silences (0 without phones)."""
    return 0 if phones is None else sum(1 for p in phones if not p.is_silence)


@dataclass
class CorpusCaptureReport:
    """What :func:`capture_corpus` did: takes ``captured`` now, ``skipped`` (complete already) and
    ``failed`` (name, one-line reason)."""

    captured: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)


def capture_corpus(
    folder: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    language: str = "en",
    face_model: str | os.PathLike | None = None,
    sync: bool = False,
    smooth: bool = False,
    openness: Callable[[AudioClip], np.ndarray] | None = None,
    jobs: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> CorpusCaptureReport:
    """Capture every video in ``folder`` (:data:`VIDEO_SUFFIXES`, with ``<name>.txt`` beside it when
    there is a transcript) into the corpus folder ``out_dir``, ``jobs`` at a time (default: the
    cores), with ``sync``, ``smooth`` and ``openness`` (a picklable function) as :func:`capture_take`
    takes them. A video whose take is
    complete in ``out_dir`` is skipped; one that fails is reported and stops nothing.
    ``progress(done, total)`` after each video."""
    root, out = Path(folder), Path(out_dir)
    if not root.is_dir():
        raise VispeechError(f"video folder not found: {root}")
    videos = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
    if not videos:
        raise VispeechError(f"{root} holds no videos ({', '.join(VIDEO_SUFFIXES)})")
    names = [v.stem for v in videos]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise VispeechError(f"two videos are named {twice[0]!r} (one take per name)")
    check_installed()
    face_model_path(face_model)
    out.mkdir(parents=True, exist_ok=True)
    report = CorpusCaptureReport()
    todo = []
    for video in videos:
        if all((out / f"{video.stem}{suffix}").is_file() for suffix in (".face.csv", ".csv")):  # the CSV last
            report.skipped += 1
        else:
            todo.append(video)
    done = report.skipped
    if progress is not None:
        progress(done, len(videos))
    face_model = str(face_model) if face_model is not None else None
    pool = ProcessPool(max_workers=min(jobs or os.cpu_count() or 1, max(len(todo), 1)))
    try:
        futures: dict[Future[str | None], Path] = {
            pool.schedule(_capture_into, (video, out, language, face_model, sync, smooth, openness)): video
            for video in todo
        }
        for future in as_completed(futures):
            try:
                failure = future.result()
            except ProcessExpired as exc:  # MediaPipe or PyAV crashed on it: that video failed, a new worker goes on
                failure = f"its worker process ended (exit code {exc.exitcode})"
            if failure is None:
                report.captured += 1
            else:
                report.failed.append((futures[future].stem, failure))
            done += 1
            if progress is not None:
                progress(done, len(videos))
    finally:
        pool.stop()
        pool.join()
    report.failed.sort()
    return report


def _capture_into(
    video: Path,
    out: Path,
    language: str,
    face_model: str | None,
    sync: bool,
    smooth: bool,
    openness: Callable[[AudioClip], np.ndarray] | None,
) -> str | None:
    """Capture one video into the corpus folder ``out`` (:func:`capture_take`); None, or why it failed."""
    transcript = video.with_suffix(".txt")
    try:
        text = " ".join(transcript.read_text(encoding="utf-8-sig").split()) if transcript.is_file() else None
        capture_take(
            video, out, text=text or None, language=language, face_model=face_model, sync=sync, smooth=smooth,
            openness=openness,
        )  # fmt: skip
        return None
    except VispeechError as exc:
        return str(exc)
    except (OSError, UnicodeDecodeError) as exc:
        return f"{type(exc).__name__}: {exc}"


def import_livelink_take(
    csv: str | os.PathLike,
    video: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    text: str | None = None,
    language: str = "en",
) -> CaptureReport:
    """Write a Live Link Face recording (the app's ``csv`` and its ``video`` with the sound) as a take
    in ``out_dir``, in the layout :func:`capture_take` writes, the iPhone's blend shapes kept as
    they are (no MediaPipe).

    The CSV's rows carry timecodes and the video a start timecode: the CSV's first row is at
    ``csv start − video start`` seconds of the sound. The take's frames start with the sound
    (frame k at k / fps); frames the CSV does not cover are left empty in ``<name>.face.csv``
    (and held from the nearest row in the Live Link CSV). Without a timecode in the video the two
    are taken to start together (the report's ``timecode_offset`` is then NaN). Raises
    :class:`VispeechError` for a CSV that starts more than 10 s away from the sound."""
    from vispeech.frontends.video import video_timecode
    from vispeech.motion.formats.livelink import parse_timecode, read_livelink_csv

    name = Path(video).stem
    files = [f.format(name=name) for f in TAKE_FILES]
    _check_take_folder(out_dir, files)
    track = read_livelink_csv(csv)
    clip = video_audio(video)
    stamp = video_timecode(video)
    offset = float("nan")
    if stamp is not None:
        timecode, rate = stamp
        offset = track.start_time - parse_timecode(timecode, max(1, round(rate or track.fps)), "video timecode")
        if abs(offset) > 10.0:
            raise VispeechError(
                f"{csv}: its first timecode is {offset:+.2f} s from the video's ({timecode}): not the same take?"
            )
    n = int(np.ceil(clip.duration * track.fps - 1e-6))
    source = np.arange(n) - (0.0 if np.isnan(offset) else offset) * track.fps  # row of the CSV at frame k
    values = np.column_stack([np.interp(source, np.arange(track.n_frames), column) for column in track.values.T])
    covered = (source > -0.5) & (source < track.n_frames - 0.5)
    phones = align(clip.samples, clip.sample_rate, text, language) if text is not None else None
    _write_take(out_dir, files, clip, np.where(covered[:, None], values, np.nan), track.channels, {}, track.fps, phones)
    return CaptureReport(
        name, n, int((~covered).sum()), track.fps, clip.duration, _spoken(phones), float("nan"), False, offset
    )
