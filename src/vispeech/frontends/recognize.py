"""Phones from English speech alone, by pocketsphinx's phone decoder.

The allphone search decodes context-independent phones of the en-us acoustic model under the
phone bigram language model both ship in the pocketsphinx wheel (``en-us-phone.lm.bin``).
Decoding covers the speech (:func:`vispeech.frontends.activity.speech_span`) widened by
:data:`MARGIN_S`; the rest is silence. pocketsphinx's phones are ARPAbet without stress;
``SIL`` and its fillers (``+NSN+``, ``+SPN+``, ...) become ``sil``.

Free phone decoding is much less accurate than forced alignment: on GRID its phone error
rate against the forced alignment is about 67 % (docs/corpus.md).
"""

from __future__ import annotations

import functools
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from vispeech.alignment.edits import edit_path
from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.activity import speech_span
from vispeech.frontends.align import FRAMES_PER_SECOND, PAD_SECONDS, SAMPLE_RATE, decode_utterance, padded_pcm
from vispeech.frontends.audio import AudioClip
from vispeech.phonetics.inventory import SILENCE, parse_symbol

MARGIN_S = 0.1
"""Seconds decoded before and after the speech."""
LANGUAGE_WEIGHT = 2.0
"""Weight of the phone language model against the acoustic scores."""
PHONE_INSERTION = 1e-3
"""Probability charged for each phone decoded (pocketsphinx's ``wip``): lower, fewer phones."""
BEAM = 1e-20
"""Pruning beam of the phone search."""

_DECODER_LOCK = threading.Lock()


def recognize_phones(audio: np.ndarray, sample_rate: int) -> PhoneSequence:
    """English phones heard in ``audio`` (float in [-1, 1] or int16, mono or ``(samples,
    channels)``, at ``sample_rate`` Hz), start/end in seconds, covering the whole audio,
    without words. Raises :class:`VispeechError` for audio that is empty, non-finite or has
    no speech, or when the decoder finds no path."""
    clip = AudioClip.from_array(audio, sample_rate)
    start, end = speech_span(clip)
    start, end = max(start - MARGIN_S, 0.0), min(end + MARGIN_S, clip.duration)
    samples = clip.resampled(SAMPLE_RATE).samples
    piece = AudioClip(samples[round(start * SAMPLE_RATE) : round(end * SAMPLE_RATE)], SAMPLE_RATE)
    decoder = _decoder()
    with _DECODER_LOCK:
        decode_utterance(decoder, padded_pcm(piece))
        if decoder.hyp() is None:
            raise VispeechError("phone recognition failed: pocketsphinx found no path through the audio")
        segments = [(s.word, s.start_frame, s.end_frame + 1) for s in decoder.seg()]

    offset = start - PAD_SECONDS
    phones: list[Phone] = []

    def add(symbol: str, a: float, b: float) -> None:
        if symbol == SILENCE and phones and phones[-1].symbol == SILENCE:
            phones[-1] = replace(phones[-1], end=b)
        else:
            phones.append(Phone(symbol, a, b))

    t = 0.0
    for name, first, stop in segments:
        a = min(max(round(first / FRAMES_PER_SECOND + offset, 3), start, t), end)  # on the 10 ms grid
        b = min(round(stop / FRAMES_PER_SECOND + offset, 3), end)
        if b - a < TIME_TOLERANCE:
            continue
        if a > t + TIME_TOLERANCE:
            add(SILENCE, t, a)
        add(_symbol(name), a, b)
        t = b
    if t < clip.duration - TIME_TOLERANCE:
        add(SILENCE, t, clip.duration)
    return PhoneSequence(phones, "en").validate()


def _symbol(name: str) -> str:
    """The inventory symbol of a pocketsphinx phone: ``SIL`` and fillers (``+NSN+``) are silence."""
    if name == "SIL" or name.startswith(("+", "<", "[")):
        return SILENCE
    return parse_symbol(name, "en")[0]


@functools.cache
def _decoder():
    import pocketsphinx

    model = Path(pocketsphinx.__file__).parent / "model" / "en-us" / "en-us-phone.lm.bin"
    return pocketsphinx.Decoder(
        samprate=SAMPLE_RATE,
        allphone=str(model),
        lm=None,
        lw=LANGUAGE_WEIGHT,
        wip=PHONE_INSERTION,
        beam=BEAM,
        pbeam=BEAM,
        bestpath=False,
        loglevel="FATAL",
    )


def match_phones(reference: PhoneSequence, hypothesis: PhoneSequence) -> tuple[int, list[tuple[Phone, Phone]]]:
    """Edit distance between the non-silence phone symbols of two sequences (substitutions,
    insertions and deletions), and the pairs of equal phones one cheapest edit path matches."""
    ref = [p for p in reference if not p.is_silence]
    hyp = [p for p in hypothesis if not p.is_silence]
    edits, pairs = edit_path([p.symbol for p in ref], [p.symbol for p in hyp])
    return edits, [(ref[i], hyp[j]) for i, j in pairs]
