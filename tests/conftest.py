"""Shared test fixtures: the acceptance sentences, the shared data folder, and :func:`require`.

Every test that needs something from its surroundings (the ``../shared`` folder, Node.js,
Chromium, an installed extra) checks for it through :func:`require` or
:func:`require_module`: on a developer's machine a missing piece skips the test; with
``CI=true`` in the environment it fails the test, so CI cannot pass by skipping.
"""

import importlib
import os
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from vispeech.alignment.phones import Phone, PhoneSequence

DATA = Path(__file__).parent / "data"
SHARED = Path(__file__).resolve().parents[2] / "shared"
CI_VALUES = ("1", "true", "yes")
"""Values of the ``CI`` environment variable (any case) under which :func:`require` fails instead of skipping."""


def in_ci() -> bool:
    """Whether the tests run under CI (``CI=true``), where nothing may be skipped for being missing."""
    return os.environ.get("CI", "").strip().lower() in CI_VALUES


def require(condition: object, what: str) -> None:
    """Go on if ``condition`` holds; otherwise skip the test, or under ``CI=true`` fail it.

    ``what`` names what is missing and how to get it, e.g. ``"Chromium (/usr/bin/chromium;
    apt-get install chromium)"``. Works in tests, fixtures and at module level.
    """
    if condition:
        return
    if in_ci():
        pytest.fail(f"CI=true and {what} is missing: a test that needs it fails under CI instead of skipping",
                    pytrace=False)
    pytest.skip(f"{what} is missing", allow_module_level=True)


def require_module(name: str, what: str | None = None) -> ModuleType:
    """The module ``name``, imported; if it cannot be imported, :func:`require` fails or skips."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        require(False, f"{what or f'the Python module {name}'} ({exc})")
        raise  # not reached: require raises


def read_sentences(language: str) -> list[str]:
    """The acceptance sentences of one language (tests/data/sentences_<lang>.txt)."""
    lines = (DATA / f"sentences_{language}.txt").read_text(encoding="utf-8").splitlines()
    return [line.strip() for line in lines if line.strip()]


@pytest.fixture
def shared_dir() -> Path:
    """The read-only ``shared`` folder beside the repository (skips when absent, fails under CI)."""
    require(SHARED.is_dir(), f"the shared data folder {SHARED}")
    return SHARED


@pytest.fixture
def grid_s1(shared_dir) -> Path:
    """GRID speaker 1 in the shared folder (``shared/data/grid_s1``; skips when absent, fails under CI)."""
    folder = shared_dir / "data" / "grid_s1"
    require(folder.is_dir(), f"GRID speaker 1 ({folder})")
    return folder


def random_sentence(rng: np.random.Generator, symbols: Sequence[str], language: str = "en") -> PhoneSequence:
    """Silence, 4–7 random phones of ``symbols`` lasting 60–200 ms each, silence."""
    phones, t = [Phone("sil", 0.0, 0.2)], 0.2
    for symbol in rng.choice(symbols, rng.integers(4, 8)):
        duration = float(rng.uniform(0.06, 0.2))
        phones.append(Phone(str(symbol), t, t + duration))
        t += duration
    phones.append(Phone("sil", t, t + 0.2))
    return PhoneSequence(phones, language)


def copy_grid_utterances(source: Path, root: Path, count: int) -> Path:
    """``root``, made a GRID folder of the first ``count`` utterances of the GRID folder ``source``."""
    import shutil

    texts = dict(line.split("\t") for line in (source / "sentences.tsv").read_text().splitlines()[1:])
    ids = sorted(path.stem for path in (source / "utterances").glob("*.flac"))[:count]
    (root / "utterances").mkdir(parents=True)
    for uid in ids:
        for ext in ("flac", "align", "csv"):
            shutil.copy(source / "utterances" / f"{uid}.{ext}", root / "utterances" / f"{uid}.{ext}")
    (root / "sentences.tsv").write_text("id\ttext\n" + "".join(f"{uid}\t{texts[uid]}\n" for uid in ids))
    return root


def resample_face_csv(path: Path, fps: float) -> None:
    """Rewrite a GRID face-track CSV at ``fps`` over the same span: channels and landmarks
    interpolated linearly (untracked frames, already filled in by the reader, become tracked)."""
    from vispeech.corpus.grid import read_face_csv, write_face_csv
    from vispeech.motion.track import Track

    track, landmarks, _ = read_face_csv(path)
    names = list(landmarks)
    both = Track(np.hstack([track.values, *landmarks.values()]), (*track.channels, *(
        f"{name}_{axis}" for name in names for axis in "xyz")), track.fps).resample(fps)
    width = len(track.channels)
    points = {name: both.values[:, width + 3 * k:width + 3 * k + 3] for k, name in enumerate(names)}
    write_face_csv(path, both.values[:, :width], track.channels, points, fps)


TINY_AUDIO_UTTERANCES = 10
"""GRID utterances the tiny audio model of :func:`tiny_audio_model` learns from (8 to train, 2 to validate)."""


@pytest.fixture(scope="session")
def tiny_audio_model(tmp_path_factory) -> Path:
    """The folder of a tiny ``audio-cnn`` (one epoch, 16 channels a layer) trained on the first
    GRID speaker-1 utterances: an audio model for the server's tests while the shipped
    ``grid-audio-cnn`` is not there (skips without ``shared/`` or torch, fails under CI)."""
    require_module("torch", "torch (the train extra)")
    source = SHARED / "data" / "grid_s1"
    require(source.is_dir(), f"GRID speaker 1 ({source})")
    from vispeech.corpus import align_corpus, read_grid
    from vispeech.models.fitting import Splits
    from vispeech.models.registry import create_model

    root = copy_grid_utterances(source, tmp_path_factory.mktemp("grid"), TINY_AUDIO_UTTERANCES)
    corpus = align_corpus(read_grid(root, cache=root / "cache"), progress=False)
    utterances = list(corpus)
    model = create_model("audio-cnn", epochs=1, channels=[16, 16, 16], pitch_copies=0)
    model.fit(Splits(utterances[:8], utterances[8:]), progress=False)
    return model.save(tmp_path_factory.mktemp("models") / "tiny-audio-cnn")
