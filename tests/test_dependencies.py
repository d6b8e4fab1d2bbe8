"""The core install stays light (issue 25): no heavy package is reachable from the core's
requirements, and the core commands import none."""

from __future__ import annotations

import re
import tomllib
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import numpy as np
import pytest
import soundfile
from packaging.requirements import Requirement

from test_cli import _imported_by
from vispeech.alignment.formats import write_textgrid
from vispeech.frontends.espeak import synthesize
from vispeech.motion.formats.livelink import write_livelink_csv
from vispeech.motion.track import Track

ROOT = Path(__file__).resolve().parents[1]
HEAVY = {"numba": "numba", "llvmlite": "llvmlite", "pandas": "pandas", "scikit-learn": "sklearn", "torch": "torch",
         "matplotlib": "matplotlib"}
"""Distributions the core must not pull (numba and llvmlite alone were 208 MB, pandas 84 MB) → their modules."""
OPTIONAL = {"librosa": "librosa", "panphon": "panphon", "scipy": "scipy"}
"""Distributions that are extras now (librosa and panphon pull numba, scikit-learn and pandas; scipy
alone was 136 of the core's 341 MiB) → their modules."""


def _name(text: str) -> str:
    return re.sub(r"[-_.]+", "-", text).lower()


def core_closure() -> dict[str, str]:
    """Every distribution the core's requirements (pyproject.toml) reach in this environment
    (markers as they evaluate here, extras followed), with the chain of requirements to it."""
    core = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["dependencies"]
    reached: dict[str, str] = {}
    queue = [(Requirement(text), "vispeech") for text in core]
    seen = set()
    while queue:
        requirement, parent = queue.pop()
        name = _name(requirement.name)
        if (name, *sorted(requirement.extras)) in seen:
            continue
        seen.add((name, *sorted(requirement.extras)))
        reached.setdefault(name, f"{parent} -> {name}")
        try:
            requires = distribution(requirement.name).requires or []
        except PackageNotFoundError:
            pytest.fail(f"{parent} -> {name}: a core requirement is not installed")
        for text in requires:
            sub = Requirement(text)
            if sub.marker is None or any(sub.marker.evaluate({"extra": e}) for e in ("", *requirement.extras)):
                queue.append((sub, reached[name]))
    return reached


def test_no_heavy_package_is_reachable_from_the_core():
    reached = core_closure()
    assert {"numpy", "soundfile", "soxr", "pocketsphinx"} <= set(reached)
    heavy = [reached[name] for name in (*HEAVY, *OPTIONAL) if name in reached]
    assert not heavy, f"the core pulls {heavy}"


@pytest.mark.parametrize("args", [
    ["animate", "speech.wav", "--model", "grid-audio-encdec", "-o", "heard"],
    ["animate", "speech.wav", "--text", "Place blue at F two now.", "-o", "aligned"],
    ["say", "Guten Morgen, wie geht es dir?", "--language", "de", "-o", "said"],
    ["animate-phones", "speech.TextGrid", "--model", "beskow-rules", "-o", "smoothed"],
], ids=["animate", "animate-text", "say-ipa", "animate-phones-beskow"])
def test_core_commands_import_nothing_heavy(tmp_path, args):
    """The core's default audio model (log-mel features), alignment of a transcript, a
    language read through IPA (PanPhon's table) and a rule model that smooths its track run
    without the heavy modules or the extras that used to pull them."""
    speech = synthesize("Place blue at F two now.", "en")
    soundfile.write(tmp_path / "speech.wav", speech.audio, speech.sample_rate)
    write_textgrid(speech.phones, tmp_path / "speech.TextGrid")
    imported = _imported_by(args, tmp_path)
    assert not imported & {*HEAVY.values(), *OPTIONAL.values()}, sorted(imported)
    assert (tmp_path / args[-1] / "animation.csv").is_file()


def test_convert_to_glb_imports_nothing_heavy(tmp_path, shared_dir):
    """Animating a head (glTF onto a GLB) needs none of the rig extra's SciPy."""
    write_livelink_csv(Track(np.zeros((3, 1)), ("jawOpen",), 30.0), tmp_path / "in.csv")
    imported = _imported_by(["convert", "in.csv", "out.glb", "--glb", str(shared_dir / "assets/ict_head.glb")],
                            tmp_path)
    assert not imported & {*HEAVY.values(), *OPTIONAL.values()}, sorted(imported)
    assert (tmp_path / "out.glb").read_bytes()[:4] == b"glTF"
