"""Shared test fixtures: the acceptance sentences and the shared data folder."""

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
SHARED = Path(__file__).resolve().parents[2] / "shared"


def read_sentences(language: str) -> list[str]:
    """The acceptance sentences of one language (tests/data/sentences_<lang>.txt)."""
    lines = (DATA / f"sentences_{language}.txt").read_text(encoding="utf-8").splitlines()
    return [line.strip() for line in lines if line.strip()]


@pytest.fixture
def shared_dir() -> Path:
    """The read-only ``shared`` folder beside the repository; skips when absent."""
    if not SHARED.is_dir():
        pytest.skip("shared/ folder not available")
    return SHARED
