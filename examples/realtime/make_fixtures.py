"""Make the recorded fixtures of the realtime examples (``fixtures/``) from espeak-ng.

    PYTHONPATH=src python examples/realtime/make_fixtures.py

espeak-ng speaks :data:`SENTENCE` (with the silences ``vispeech say`` puts around speech) and
knows when each word and phone starts: those are the timings a voice service would send with
the audio. The audio is kept once, as ``fixtures/speech.flac`` (16-bit, 16 kHz mono); each
fixture is the service's stream of events as JSON lines, in the order the service sends them,
with one liberty: where the service carries base64 audio (``delta``, ``audio_base64``,
``audio_data``) the line says which samples of ``speech.flac`` it carried (``"samples": [a, b]``),
and :func:`relay.read_fixture` puts the base64 back.

- ``openai.jsonl``: OpenAI Realtime (Gemini Live is alike): ``response.output_audio.delta``
  events of PCM (about 0.15 and 0.25 s each), then ``response.output_audio.done``; no timings.
- ``elevenlabs.jsonl``: ElevenLabs' stream with timestamps: chunks of 0.25 s of audio, each
  with the ``alignment`` of the characters starting in it (``characters``,
  ``character_start_times_seconds``, ``character_end_times_seconds``, seconds from the start),
  so a word's characters may come in two chunks.
- ``azure.jsonl``: Azure Speech: ``Synthesizing`` audio chunks of 0.2 s, ``WordBoundary``
  events (``text``, ``audio_offset`` and ``duration`` in 100-ns ticks, ``boundary_type``: the
  final full stop is a ``Punctuation`` boundary) sent just before the chunk in which the word
  starts, and ``VisemeReceived`` events (``viseme_id`` 0–21, ``audio_offset``) sent just after
  the chunk they fall in: timings ahead of their audio and behind it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import soundfile
import soxr

from vispeech.frontends.espeak import synthesize
from vispeech.pipeline import LEADING_SILENCE, TRAILING_SILENCE, padded

SENTENCE = "Please bring my map back by noon."
RATE = 16000
FOLDER = Path(__file__).parent / "fixtures"
TICKS = 10_000_000
"""Azure's ticks (100 ns) per second."""

AZURE_VISEME = {
    "sil": 0, "AE": 1, "AH": 1, "AA": 2, "AO": 3, "EH": 4, "UH": 4, "EY": 4, "ER": 5, "IH": 6, "IY": 6, "Y": 6,
    "UW": 7, "W": 7, "OW": 8, "AW": 9, "OY": 10, "AY": 11, "HH": 12, "R": 13, "L": 14, "S": 15, "Z": 15,
    "SH": 16, "ZH": 16, "CH": 16, "JH": 16, "DH": 17, "F": 18, "V": 18, "T": 19, "D": 19, "N": 19, "TH": 19,
    "K": 20, "G": 20, "NG": 20, "P": 21, "B": 21, "M": 21,
}
"""Azure's viseme id of each English phone (Azure's viseme table)."""


def write_lines(name: str, events: list[dict]) -> None:
    with open(FOLDER / name, "w", encoding="utf-8") as out:
        for event in events:
            out.write(json.dumps(event, separators=(",", ":")) + "\n")


def chunks(n: int, sizes: list[int]) -> list[tuple[int, int]]:
    """``[a, b)`` sample ranges over ``n`` samples, of the ``sizes`` in turn."""
    out, a, k = [], 0, 0
    while a < n:
        b = min(n, a + sizes[k % len(sizes)])
        out.append((a, b))
        a, k = b, k + 1
    return out


def characters(text: str, words) -> list[tuple[str, float, float]]:
    """Each character of ``text`` with its times: a word's characters share its span, the
    characters between words the gap between them."""
    out: list[tuple[str, float, float]] = []
    tokens = text.split(" ")
    assert len(tokens) == len(words)
    for k, (token, word) in enumerate(zip(tokens, words)):
        if k:
            out.append((" ", out[-1][2], word.start))
        step = (word.end - word.start) / len(token)
        out += [(c, word.start + i * step, word.start + (i + 1) * step) for i, c in enumerate(token)]
    return out


def main() -> None:
    speech = padded(synthesize(SENTENCE, "en"), LEADING_SILENCE, TRAILING_SILENCE)
    audio = soxr.resample(speech.audio, speech.sample_rate, RATE, quality="HQ")
    FOLDER.mkdir(exist_ok=True)
    soundfile.write(FOLDER / "speech.flac", np.clip(audio, -1, 1), RATE, subtype="PCM_16")
    n, words = len(audio), speech.phones.words

    openai = [{"type": "response.output_audio.delta", "samples": [a, b]} for a, b in chunks(n, [2400, 4000])]
    write_lines("openai.jsonl", [*openai, {"type": "response.output_audio.done"}])

    timed = characters(SENTENCE, words)
    eleven = []
    for a, b in chunks(n, [4000]):
        inside = [c for c in timed if a / RATE <= c[1] < b / RATE or (b == n and c[1] >= a / RATE)]
        alignment = None if not inside else {
            "characters": [c for c, _, _ in inside],
            "character_start_times_seconds": [round(s, 4) for _, s, _ in inside],
            "character_end_times_seconds": [round(e, 4) for _, _, e in inside],
        }
        eleven.append({"samples": [a, b], "alignment": alignment})
    write_lines("elevenlabs.jsonl", eleven)

    boundaries = [{"event": "WordBoundary", "text": w.text, "audio_offset": round(w.start * TICKS),
                   "duration": round((w.end - w.start) * TICKS), "boundary_type": "Word"} for w in words]
    boundaries.append({"event": "WordBoundary", "text": ".", "audio_offset": round(words[-1].end * TICKS),
                       "duration": 0, "boundary_type": "Punctuation"})
    visemes = [{"event": "VisemeReceived", "viseme_id": AZURE_VISEME[p.symbol], "audio_offset": round(p.start * TICKS)}
               for p in speech.phones.phones]
    azure = []
    for a, b in chunks(n, [3200]):
        azure += [e for e in boundaries if a / RATE <= e["audio_offset"] / TICKS < b / RATE]
        azure.append({"event": "Synthesizing", "samples": [a, b]})
        azure += [e for e in visemes if a / RATE <= e["audio_offset"] / TICKS < b / RATE]
    write_lines("azure.jsonl", [*azure, {"event": "SynthesisCompleted"}])


if __name__ == "__main__":
    main()
