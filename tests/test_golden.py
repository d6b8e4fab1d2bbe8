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


_SPEECH = json.loads((GOLDEN / "speech.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("entry", _SPEECH, ids=[e["text"][:24] for e in _SPEECH])
def test_espeak_gives_the_golden_swedish_and_english_phones(entry: dict) -> None:
    """The curated front end still speaks sv and en as it did before other languages came
    through IPA: same phones, stresses, words and times (so the same tracks, given the above)."""
    from vispeech.frontends.espeak import synthesize

    phones = synthesize(entry["text"], entry["language"]).phones.to_dict()
    golden = {k: v for k, v in entry.items() if k != "text"}
    assert [(p["symbol"], p["stress"], p["word"]) for p in phones["phones"]] == \
        [(p["symbol"], p["stress"], p["word"]) for p in golden["phones"]]
    assert [w["text"] for w in phones["words"]] == [w["text"] for w in golden["words"]]
    np.testing.assert_allclose([(p["start"], p["end"]) for p in phones["phones"]],
                               [(p["start"], p["end"]) for p in golden["phones"]], atol=1e-9)
