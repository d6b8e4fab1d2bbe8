"""Every shipped and data-free model reproduces its golden tracks (recorded by tests/golden/record.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.pipeline import animate, animate_many

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


@pytest.mark.parametrize("model", MODELS)
def test_animating_many_at_once_gives_each_track_bit_for_bit(model: str) -> None:
    """animate_many (grid-tdnn: every utterance through the kernels and the recurrence together,
    a fresh model with nothing cached) gives what animate gives each alone; a sequence it must
    refuse is reported in its place and the others are animated all the same."""
    sequences = [PhoneSequence.from_dict(entry) for entry in _PHONES]
    unknown = PhoneSequence([Phone("zzz", 0.0, 0.5)], "en")  # refused by the model, not before it
    together = animate_many([*sequences[:2], PhoneSequence([], "en"), *sequences[2:], unknown], model, 30.0)
    assert isinstance(together[2], VispeechError) and "empty" in str(together[2])
    assert isinstance(together[-1], VispeechError) and "zzz" in str(together[-1])
    del together[2], together[-1]
    for entry, sequence, track in zip(_PHONES, sequences, together, strict=True):
        alone = animate(sequence, model, 30.0)
        assert isinstance(track, type(alone)) and track.channels == alone.channels
        np.testing.assert_array_equal(track.values, alone.values, err_msg=f"{model}: {entry['text']}")


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
