"""Reader for a folder of Live Link Face takes (the thesis's capture layout).

Each take ``<name>`` is ``<name>.csv`` (Live Link Face CSV), ``<name>.wav`` (or ``.flac``)
and its transcript: ``<name>.TextGrid`` (words and phones, e.g. from the Montreal Forced
Aligner) or ``<name>.txt`` (plain text). A take captured from video
(:mod:`vispeech.corpus.capture`) also has ``<name>.face.csv``: its face track in GRID's layout,
read instead of the CSV for its landmarks and its untracked frames (the frame mask).
"""

from __future__ import annotations

import os
from pathlib import Path

from vispeech.alignment.formats import read_alignment
from vispeech.corpus.cache import CorpusCache, content_hash
from vispeech.corpus.corpus import Corpus, Utterance, check_durations, recorded_track, report_problem
from vispeech.corpus.grid import read_face_csv
from vispeech.errors import VispeechError
from vispeech.frontends.audio import audio_duration
from vispeech.motion.formats.livelink import read_livelink_csv
from vispeech.motion.track import Track

AUDIO_SUFFIXES = (".wav", ".flac")
FACE_SUFFIX = ".face.csv"
TAKE_SUFFIXES = (".csv", *AUDIO_SUFFIXES, ".txt", ".textgrid")


def read_takes(
    directory: str | os.PathLike,
    *,
    language: str = "sv",
    strict: bool = False,
    cache: str | os.PathLike | None = None,
) -> Corpus:
    """Read a folder of takes into a :class:`Corpus` of ``language`` (``"sv"`` for the thesis).

    A take's phones and words come from its TextGrid when it has one (otherwise align the
    corpus, English only). The corpus frame rate and channels are those of the first good
    take. Takes with a missing, unreadable or empty file, a track whose length differs from
    the audio's, or another frame rate or channel set than the first are skipped with a
    :class:`~vispeech.corpus.corpus.CorpusWarning` naming each (listed in
    ``Corpus.problems``), or raise :class:`VispeechError` if ``strict``. ``cache`` overrides
    the cache folder (default: see :mod:`vispeech.corpus.cache`).
    """
    root = Path(directory)
    if not root.is_dir():
        raise VispeechError(f"takes folder not found: {root}")
    files = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in TAKE_SUFFIXES)
    names = sorted({p.stem for p in files} - {p.stem for p in files if p.name.lower().endswith(FACE_SUFFIX)})
    if not names:
        raise VispeechError(f"{root} holds no takes (<name>.csv, <name>.wav, <name>.txt or .TextGrid)")

    utterances: list[Utterance] = []
    problems: list[str] = []
    for name in names:
        try:
            utterance = _read_take(root, name, language)
            if utterances:
                first, track = recorded_track(utterances[0]), recorded_track(utterance)
                if abs(track.fps - first.fps) > 1e-3:
                    raise VispeechError(f"its frame rate {track.fps:g} fps differs from {first.fps:g} fps")
                if track.channels != first.channels:
                    raise VispeechError("its CSV columns differ from the first take's")
        except VispeechError as exc:
            report_problem(problems, f"skipped take {name}: {exc}", strict)
            continue
        utterances.append(utterance)

    first_track = utterances[0].track if utterances else None
    return Corpus(
        name=root.resolve().name,
        utterances=utterances,
        fps=first_track.fps if first_track else 60.0,
        channels=first_track.channels if first_track else (),
        language=language,
        root=root,
        problems=problems,
        cache=CorpusCache.for_corpus(root.resolve().name, content_hash(files, root), cache),
    )


def _find(root: Path, name: str, suffixes: tuple[str, ...]) -> Path | None:
    for suffix in suffixes:
        for candidate in (root / f"{name}{suffix}", root / f"{name}{suffix.upper()}"):
            if candidate.is_file():
                return candidate
    return None


def _read_take(root: Path, name: str, language: str) -> Utterance:
    csv_path = _find(root, name, (".csv",))
    audio_path = _find(root, name, AUDIO_SUFFIXES)
    textgrid_path = _find(root, name, (".TextGrid", ".textgrid"))
    text_path = _find(root, name, (".txt",))
    expected = (
        (f"{name}.csv", csv_path),
        (f"{name}.wav", audio_path),
        (f"{name}.txt or .TextGrid", textgrid_path or text_path),
    )
    absent = [what for what, path in expected if path is None]
    if absent:
        raise VispeechError(f"missing {', '.join(absent)}")
    assert csv_path is not None and audio_path is not None  # none is absent

    phones = None
    if textgrid_path is not None:
        phones = read_alignment(textgrid_path, language=language)
        text = " ".join(w.text for w in phones.words)
        if not text:
            raise VispeechError(f"{textgrid_path.name} has no words tier or no words")
    else:
        assert text_path is not None  # none is absent: without a TextGrid, the transcript
        try:
            text = " ".join(text_path.read_text(encoding="utf-8-sig").split())
        except (OSError, UnicodeDecodeError) as exc:
            raise VispeechError(f"unreadable {text_path.name}: {exc}") from None
        if not text:
            raise VispeechError(f"empty transcript {text_path.name}")

    landmarks = mask = None
    face_path = _find(root, name, (FACE_SUFFIX,))
    if face_path is not None:
        track, landmarks, mask = read_face_csv(face_path)
    else:
        track = read_livelink_csv(csv_path)
    if track.start_time:  # takes keep wall-clock timecodes; the audio starts at the first frame
        track = Track(track.values, track.channels, track.fps)
    duration = audio_duration(audio_path)
    check_durations(track, duration)
    return Utterance(
        id=name,
        text=text,
        audio_path=audio_path,
        duration=duration,
        track=track,
        words=list(phones.words) if phones is not None else [],
        phones=phones,
        landmarks=landmarks,
        frame_mask=mask,
    )
