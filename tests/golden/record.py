"""Record the golden tracks that ``tests/test_golden.py`` reproduces.

Run once, from the repository root, before a change that must not alter any model's output::

    python tests/golden/record.py              # every model of MODELS, anew
    python tests/golden/record.py grid-ohman   # add (or replace) one model, keeping the others

It writes ``tests/golden/phones.json`` (the espeak-ng phones of the 20 acceptance sentences,
kept so that later runs do not depend on espeak-ng's run-to-run jitter),
``tests/golden/speech.json`` (the same sentences' phones as reproducible espeak-ng gives them
today, which the front end must keep giving: recorded at commit caf6edb, before espeak-ng's
other languages were read through IPA, issue 14) and
``tests/golden/tracks.npz`` (for every model and sentence, the post-processed track at
30 fps: float32 values, with the channel names in ``channels/<model>``).
First recorded at commit 7c41688, before the model-contract rework (issue 7); the fitted
dominance models shipped by that rework (grid-cohen-massaro, grid-ohman) were added after it.
Recorded again when post-processing began to open the vowels next to bilabials and
labiodentals (``open_vowels``, issue 10): every change of a track there is that step's; again
when it began to add the tongue channels (``postprocess.tongue``, issue 10); and again when it
began to bring the mouth to rest in silence (``postprocess.rest``, issue 26): 49 of 14,624
frames changed, all in the three pauses longer than 0.2 s (0.23-0.35 s), none in speech.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MODELS = ("baseline", "beskow-rules", "cohen-massaro", "ohman", "grid-tdnn", "grid-tdnn-lowlatency",
          "grid-cohen-massaro", "grid-ohman")
FPS = 30.0


def main() -> None:
    from vispeech.alignment.phones import PhoneSequence
    from vispeech.frontends.espeak import synthesize
    from vispeech.pipeline import animate

    sentences = [(lang, line.strip()) for lang in ("en", "sv")
                 for line in (HERE.parent / "data" / f"sentences_{lang}.txt").read_text(encoding="utf-8").splitlines()
                 if line.strip()]
    phones_path = HERE / "phones.json"
    if phones_path.is_file():
        recorded = json.loads(phones_path.read_text(encoding="utf-8"))
    else:
        recorded = [{"text": text, **synthesize(text, lang).phones.to_dict()} for lang, text in sentences]
        phones_path.write_text(json.dumps(recorded, indent=1) + "\n", encoding="utf-8")
    speech_path = HERE / "speech.json"
    if not speech_path.is_file():
        speech = [{"text": text, **synthesize(text, lang).phones.to_dict()} for lang, text in sentences]
        speech_path.write_text(json.dumps(speech, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    only = sys.argv[1:]
    arrays: dict[str, np.ndarray] = {}
    if only and (HERE / "tracks.npz").is_file():
        with np.load(HERE / "tracks.npz") as kept:
            arrays = {key: kept[key] for key in kept.files if _model_of(key) not in only}
    for model in only or MODELS:
        for i, entry in enumerate(recorded):
            phones = PhoneSequence.from_dict(entry)
            track = animate(phones, model, FPS)
            arrays[f"{model}/{i}"] = track.values.astype(np.float32)
            arrays[f"channels/{model}"] = np.array(track.channels)
    np.savez_compressed(HERE / "tracks.npz", **arrays)
    print(f"{len(recorded)} sentences x {len(only or MODELS)} models -> {HERE / 'tracks.npz'}", file=sys.stderr)


def _model_of(key: str) -> str:
    """The model an array of tracks.npz belongs to (``<model>/<sentence>`` or ``channels/<model>``)."""
    return key.split("/", 1)[1] if key.startswith("channels/") else key.rsplit("/", 1)[0]


if __name__ == "__main__":
    main()
