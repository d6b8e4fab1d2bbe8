"""Every shipped and data-free model reproduces its golden tracks (recorded by tests/golden/record.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vispeech.alignment.phones import PhoneSequence
from vispeech.pipeline import animate

GOLDEN = Path(__file__).parent / "golden"
_TRACKS = np.load(GOLDEN / "tracks.npz")
_PHONES = json.loads((GOLDEN / "phones.json").read_text(encoding="utf-8"))
MODELS = sorted({key.split("/", 1)[1] for key in _TRACKS.files if key.startswith("channels/")})


@pytest.mark.parametrize("model", MODELS)
def test_model_reproduces_its_golden_tracks(model: str) -> None:
    channels = tuple(_TRACKS[f"channels/{model}"].tolist())
    for i, entry in enumerate(_PHONES):
        track = animate(PhoneSequence.from_dict(entry), model, 30.0)
        assert track.channels == channels, (model, entry["text"])
        np.testing.assert_allclose(track.values, _TRACKS[f"{model}/{i}"], atol=1e-5, rtol=0,
                                   err_msg=f"{model}: {entry['text']}")
