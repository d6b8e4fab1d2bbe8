"""Forced alignment of speech with its transcript: pocketsphinx for English, DTW against
espeak-ng (:mod:`vispeech.frontends.dtw_align`) for Swedish and as an alternative for English.

pocketsphinx's wheel ships the en-us acoustic model and CMUdict, so nothing is downloaded.
Phones come as ARPAbet without stress (the shipped dictionary has no stress digits, so every
phone gets ``stress=0``) and silences as ``sil``.

pocketsphinx aligns in two passes: words by a search through a grammar of the transcript,
then phones (and states) inside those words. Runs of exactly zero samples, which synthetic
speech and the silence padded around every clip have, give frames of zero energy that derail
the word search ("Final result does not match the grammar"; no words, so setting up the
phone pass fails with "Failed to set up sub-word alignment"). So the audio gets ±1 LSB of
deterministic triangular dither; if the word search still finds no path (very fast or noisy
speech), it is run once more with the beams opened to :data:`WIDE_BEAM`. If the phone pass
fails (pocketsphinx's issue #339), each word's span is shared evenly among the phones of the
pronunciation the word pass chose. pocketsphinx aligns in a worker process
(:mod:`vispeech.frontends.isolation`), espeak-ng too: a crash or hang on one recording is a
:class:`~vispeech.errors.NativeFailure`.

How well a transcript fits the audio (:func:`transcript_fit`) is the mean log-likelihood ratio
per frame, over the words' span, of the transcript's state alignment against that of the phones
a free phone loop (pocketsphinx's allphone search, its phone language model weighed as the
acoustics are: :data:`LOOP_LANGUAGE_WEIGHT`) hears: near 0 or above when the audio says the
transcript, far below when it says something else. The loop hears the words' span and
:data:`FIT_MARGIN` around it, normalised by the cepstral mean of the whole recording, so that its
frames are those the transcript was aligned on. :func:`align` refuses a transcript
whose fit is below ``min_fit`` (:data:`MIN_FIT` where :func:`vispeech.pipeline.listen` asks).
"""

from __future__ import annotations

import functools
import re
import threading

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.frontends.activity import speech_span
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.dtw_align import dtw_align
from vispeech.frontends.isolation import run_isolated
from vispeech.phonetics.inventory import SILENCE, get_inventory, is_silence, parse_symbol

SAMPLE_RATE = 16000
"""The acoustic model's sample rate in Hz; other rates are resampled to it."""

PAD_SECONDS = 0.5
"""Silence added before and after the audio: without it the word search can fail."""

FRAMES_PER_SECOND = 100
"""pocketsphinx reports times in 10 ms frames."""

BEAM, WORD_BEAM = 1e-100, 1e-80
"""The beams of the first try (``beam`` and ``pbeam``; ``wbeam``)."""
WIDE_BEAM = 1e-300
"""Every beam of the second try, when the first finds no path (about 40 % slower)."""

MIN_FIT = -10.0
"""The least :func:`transcript_fit` of a transcript that fits its audio. On 100 grid_s1 utterances
(``benchmarks/bench_transcript_fit.py --choose``) the true transcripts fit from -7.4 up, those of
other utterances 91 of 100 below -10 (the rest differ from the true ones in a few similar-sounding
words); on 20 others every true transcript fits from -6.6 up and every other one is below -11.4.
The margin below the lowest true fit keeps true transcripts taken: Whisper's transcript of
espeak-ng's synthetic speech, which the acoustic model hears worse, fits -8.0."""

LOOP_LANGUAGE_WEIGHT = 1.0
"""How much the phone loop of :func:`transcript_fit` weighs its phone language model against the
acoustics (pocketsphinx's ``lw``, 6.5 by default, is for words). Weighed as for words, the loop
hears few, long phones that fit the audio worse than many a wrong transcript; at 1 it hears about
twice as many. On the utterances of :data:`MIN_FIT`, 2 below the least true fit, 96 of the 100
wrong transcripts are below rather than 80."""

FIT_MARGIN = 0.3
"""Seconds of audio before the transcript's first word and after its last that the phone loop of
:func:`transcript_fit` hears, not the rest (a 3-s GRID clip and its padding are about half
silence; the loop and the re-alignment of what it heard are two thirds of the fit's time)."""
_FRAME_BYTES = 2 * SAMPLE_RATE // FRAMES_PER_SECOND
"""Bytes of 16-bit samples between the starts of two frames."""
_WINDOW_BYTES = 2 * 410
"""Bytes of 16-bit samples in a frame's analysis window (pocketsphinx's 25.625 ms)."""

MIN_PHONE_FRAMES = 3
"""Frames each phone needs at least: the acoustic model's phones have three states."""

METHODS = ("pocketsphinx", "dtw")
"""Alignment methods: pocketsphinx (English only; the default for English) and DTW against
espeak-ng (any language espeak speaks; the default for the others)."""

ALIGNER = "pocketsphinx 5.1.1 dithered, wide-beam retry; espeak-ng DTW log-mel 1"
"""Names the aligners in cached results, so that a change of aligner invalidates them."""

EDGE_PUNCTUATION = "\"'.,;:!?()[]{}«»“”‘’—–-"
"""What :func:`normalize_transcript` strips from the ends of words."""
_ALTERNATE = re.compile(r"\(\d+\)$")
_LOOP_WORD = "vispeech-phone-"
"""Prefix of the one-phone words the phone loop's phones are aligned as."""
_DECODER_LOCK = threading.Lock()  # one shared decoder per process

_Segments = list[tuple[str, list[tuple[str, int, int]]]]
"""Words (pocketsphinx names, fillers included) with their phones: (label, start frame, frames)."""


class TranscriptMismatch(VispeechError):
    """The transcript does not fit the audio (:func:`transcript_fit` below the least asked for)."""


def align(
    audio: np.ndarray,
    sample_rate: int,
    text: str,
    language: str = "en",
    method: str | None = None,
    min_fit: float | None = None,
) -> PhoneSequence:
    """Time-align ``text`` with ``audio``: phones and words with start/end in seconds.

    ``audio`` holds samples (float in [-1, 1] or int16), mono or ``(samples, channels)``
    (channels are averaged) at ``sample_rate`` Hz. ``method`` is one of :data:`METHODS`;
    by default pocketsphinx for ``"en"`` and DTW otherwise. The result covers the whole audio:
    silence before, between and after words is ``sil``. Raises :class:`VispeechError` for an
    unknown method or language, pocketsphinx with a language other than ``"en"``, words missing
    from the pronouncing dictionary (named), empty text, audio that is empty, non-finite or has
    no speech, or a failed alignment (saying where it failed); :class:`TranscriptMismatch` when
    pocketsphinx aligns a transcript whose :func:`transcript_fit` is below ``min_fit``
    (``None``: any is taken; DTW alignment is not scored).
    """
    clip = AudioClip.from_array(audio, sample_rate)
    method = method or default_method(language)
    if method == "dtw":
        return dtw_align(clip, text, language)
    if method != "pocketsphinx":
        raise VispeechError(f"unknown alignment method {method!r} (use {' or '.join(METHODS)})")
    if language != "en":
        raise VispeechError(f"pocketsphinx aligns English only (language 'en'), not {language!r}; use the dtw method")
    return run_isolated("pocketsphinx", "this recording and transcript", _pocketsphinx_align, clip, text, min_fit)


def normalize_transcript(text: str) -> list[str]:
    """Lower-case words of ``text`` with punctuation stripped from their edges."""
    words = [w.strip(EDGE_PUNCTUATION).lower() for w in text.split()]
    words = [w for w in words if w]
    if not words:
        raise VispeechError("the transcript has no words")
    return words


def in_dictionary(word: str) -> bool:
    """Whether pocketsphinx's pronouncing dictionary (CMUdict, lower case, no stress) has ``word``:
    every word of an English transcript must be there for :func:`align`."""
    return _decoder().lookup_word(word) is not None


def padded_pcm(clip: AudioClip) -> bytes:
    """The clip as pocketsphinx takes it: 16 kHz 16-bit PCM with :data:`PAD_SECONDS` of silence
    at each end and ±1 LSB of triangular dither (the same for the same clip)."""
    pad = np.zeros(round(PAD_SECONDS * SAMPLE_RATE))
    samples = np.concatenate([pad, clip.resampled(SAMPLE_RATE).samples * 32767.0, pad])
    samples += np.random.default_rng(0).triangular(-1.0, 0.0, 1.0, samples.size)
    return np.clip(np.round(samples), -32768, 32767).astype("<i2").tobytes()


def _pocketsphinx_align(clip: AudioClip, text: str, min_fit: float | None) -> PhoneSequence:
    words = normalize_transcript(text)
    decoder = _decoder()
    unknown = [w for w in dict.fromkeys(words) if not in_dictionary(w)]
    if unknown:
        raise VispeechError(f"words not in the pronouncing dictionary: {', '.join(unknown)}")
    n_phones = sum(len(decoder.lookup_word(w).split()) for w in words)
    needed = n_phones * MIN_PHONE_FRAMES / FRAMES_PER_SECOND
    if clip.duration < needed:
        raise VispeechError(
            f"alignment failed: {clip.duration:.2f} s of audio is too short for the "
            f"{n_phones} phones of the transcript (at least {needed:.2f} s)"
        )
    speech_span(clip)  # refuses silence: pocketsphinx would put the words anywhere in it
    raw = padded_pcm(clip)
    with _DECODER_LOCK:
        words_found = _word_pass(decoder, raw, words)
        if words_found is None:
            raise VispeechError(_no_path(decoder, raw, words))
        try:
            segments = _phone_pass(decoder, raw)
        except RuntimeError:
            segments = _shared_spans(decoder, words_found)
        else:
            if min_fit is not None and (fit := _fit(decoder, raw)) < min_fit:
                raise TranscriptMismatch(
                    f"the transcript does not fit the audio (fit {fit:.1f}, below {min_fit:g}): does the audio say it?"
                )
    return _to_phone_sequence(segments, clip.duration)


def transcript_fit(clip: AudioClip, text: str) -> float:
    """How well English ``text`` fits ``clip`` (see the module docstring): about 0 or above when the
    audio says it; ``nan`` when pocketsphinx cannot tell (its phone pass failed)."""
    words = normalize_transcript(text)
    raw = padded_pcm(clip)
    decoder = _decoder()
    with _DECODER_LOCK:
        if _word_pass(decoder, raw, words) is None:
            raise VispeechError(_no_path(decoder, raw, words))
        try:
            _phone_pass(decoder, raw)
        except RuntimeError:
            return float("nan")
        return _fit(decoder, raw)


def _fit(decoder, raw: bytes) -> float:
    """The transcript fit of the alignment ``decoder``'s last phone pass made in ``raw`` (``nan`` when
    the phone loop's phones cannot be aligned)."""
    words = [w for w in decoder.get_alignment() if not w.name.startswith(("<", "["))]
    first, end = words[0].start, words[-1].start + words[-1].duration
    forced = _frame_scores(decoder, end)
    start = max(first - round(FIT_MARGIN * FRAMES_PER_SECOND), 0)
    stop = end + round(FIT_MARGIN * FRAMES_PER_SECOND)
    piece = raw[start * _FRAME_BYTES : stop * _FRAME_BYTES + _WINDOW_BYTES]
    mean = decoder.get_cmn()
    loop = _phone_loop()
    decode_utterance(loop, piece, mean)
    heard = [s.word.lower() for s in loop.seg() if s.word != "SIL" and not s.word.startswith(("+", "("))]
    realigner = _realigner()
    if not heard or _word_pass(realigner, piece, [_LOOP_WORD + phone for phone in heard], mean) is None:
        return float("nan")
    try:
        _phone_pass(realigner, piece, mean)
    except RuntimeError:
        return float("nan")
    return float(np.mean(forced[first:end] - _frame_scores(realigner, end - start)[first - start :]))


def _frame_scores(decoder, n_frames: int) -> np.ndarray:
    """Acoustic score of each of the first ``n_frames`` frames in the last phone pass (each state's
    score shared evenly among its frames)."""
    scores = np.zeros(n_frames)
    for word in decoder.get_alignment():
        for phone in word:
            for state in phone:
                scores[state.start : state.start + state.duration] = state.score / max(state.duration, 1)
    return scores


def _word_pass(decoder, raw: bytes, words: list[str], mean: str | None = None) -> list[tuple[str, int, int]] | None:
    """Words and fillers found by the word search, ``(name, first frame, last frame)``; tried with
    the usual beams, then with :data:`WIDE_BEAM`; ``None`` if neither finds a path."""
    for beam, word_beam in ((BEAM, WORD_BEAM), (WIDE_BEAM, WIDE_BEAM)):
        decoder.config["beam"], decoder.config["pbeam"], decoder.config["wbeam"] = beam, beam, word_beam
        decoder.set_align_text(" ".join(words))  # the search reads the beams when it is set up
        try:
            decode_utterance(decoder, raw, mean)
        except RuntimeError:
            continue
        if decoder.hyp() is not None:
            return [(s.word, s.start_frame, s.end_frame) for s in decoder.seg()]
    return None


def _phone_pass(decoder, raw: bytes, mean: str | None = None) -> _Segments:
    """Phones inside the words the last word pass found; raises RuntimeError when pocketsphinx fails."""
    decoder.set_alignment()
    decode_utterance(decoder, raw, mean)
    return [(w.name, [(p.name, p.start, p.duration) for p in w]) for w in decoder.get_alignment()]


def _no_path(decoder, raw: bytes, words: list[str]) -> str:
    """Why the word search failed: the first word from which no prefix of the transcript aligns
    (found by bisection on the prefix length)."""
    aligned, failed = 0, len(words)  # a prefix of `aligned` words aligns, one of `failed` does not
    while failed - aligned > 1:
        middle = (aligned + failed) // 2
        if _word_pass(decoder, raw, words[:middle]) is None:
            failed = middle
        else:
            aligned = middle
    return (
        f"alignment failed: no path through the audio from word {aligned + 1} of {len(words)} "
        f"({words[aligned]!r}) on; does the audio say the transcript?"
    )


def _shared_spans(decoder, words_found: list[tuple[str, int, int]]) -> _Segments:
    """The word search's spans as segments, each word's frames shared evenly among its phones."""
    segments: _Segments = []
    for name, first, last in words_found:
        if name.startswith(("<", "[")):
            segments.append((name, [(SILENCE, first, last - first + 1)]))
            continue
        labels = decoder.lookup_word(name).split()
        edges = np.linspace(first, last + 1, len(labels) + 1).round().astype(int)
        spans = zip(labels, edges[:-1], edges[1:], strict=True)
        segments.append((name, [(label, int(a), int(b - a)) for label, a, b in spans]))
    return segments


def default_method(language: str) -> str:
    """The method :func:`align` takes for ``language`` by default: pocketsphinx for ``"en"``, DTW otherwise."""
    return "pocketsphinx" if language == "en" else "dtw"


def load_decoders() -> None:
    """Load pocketsphinx's decoders, the aligner's and the fit's two (about 0.4 s), in this
    process now: the processes forked from it afterwards (a batch's workers and their native
    workers, :mod:`vispeech.frontends.isolation`) share them instead of each loading its own."""
    _decoder()
    _realigner()
    _phone_loop()


def _new_decoder(**options):
    """A pocketsphinx decoder of the shipped en-us model at :data:`SAMPLE_RATE`, with this module's beams."""
    from pocketsphinx import Decoder

    return Decoder(
        samprate=SAMPLE_RATE,
        lm=None,
        bestpath=False,
        beam=BEAM,
        wbeam=WORD_BEAM,
        pbeam=BEAM,
        loglevel="FATAL",
        **options,
    )


@functools.cache
def _decoder():
    """The aligner: the transcript's words, then their phones, in a whole recording."""
    return _new_decoder()


@functools.cache
def _realigner():
    """The aligner of :func:`transcript_fit`'s phone loop's phones, each a word of its own, in a
    piece of a recording (normalised live: :func:`decode_utterance`)."""
    decoder = _new_decoder(cmn="live")
    for phone in get_inventory("en").symbols:
        if not is_silence(phone):
            decoder.add_word(_LOOP_WORD + phone.lower(), phone, False)
    return decoder


@functools.cache
def _phone_loop():
    """pocketsphinx's allphone search: the phones heard, under the shipped phone language model, in
    a piece of a recording (normalised live: :func:`decode_utterance`)."""
    from pocketsphinx import get_model_path

    return _new_decoder(allphone=f"{get_model_path()}/en-us/en-us-phone.lm.bin", lw=LOOP_LANGUAGE_WEIGHT, cmn="live")


def decode_utterance(decoder, raw: bytes, mean: str | None = None) -> None:
    """Decode ``raw`` (:func:`padded_pcm`, or a piece of it) as one utterance, its features computed
    afresh: without resetting them pocketsphinx carries a running cepstral mean from one utterance
    to the next, and a result would depend on what was decoded before. The cepstral mean is that
    of ``raw`` (``None``) or ``mean`` (``get_cmn()`` of the decoder that decoded the whole of
    which ``raw`` is a piece, so that the piece's frames are the whole's; ``decoder`` must then
    normalise live, ``cmn="live"``, which starts from ``mean`` and leaves it only slowly)."""
    decoder.reinit_feat()
    if mean is not None:
        decoder.set_cmn(mean)
    decoder.start_utt()
    decoder.process_raw(raw, full_utt=mean is None)
    decoder.end_utt()


def _to_phone_sequence(segments: _Segments, duration: float) -> PhoneSequence:
    """Words and phones from pocketsphinx frames: pad removed, clipped to the audio, silences merged."""
    offset = round(PAD_SECONDS * FRAMES_PER_SECOND)
    words: list[Word] = []
    phones: list[Phone] = []
    for name, word_phones in segments:
        word_index = None
        if not name.startswith(("<", "[")):
            word_index = len(words)
        for label, start_frame, n_frames in word_phones:
            start = min(max((start_frame - offset) / FRAMES_PER_SECOND, 0.0), duration)
            end = min(max((start_frame + n_frames - offset) / FRAMES_PER_SECOND, 0.0), duration)
            if end - start < TIME_TOLERANCE:
                continue
            symbol, stress = parse_symbol(label, "en")
            if symbol == SILENCE and phones and phones[-1].symbol == SILENCE:
                phones[-1] = Phone(SILENCE, phones[-1].start, end)
                continue
            phones.append(Phone(symbol, start, end, None if symbol == SILENCE else word_index, stress))
        if word_index is not None:
            own = [p for p in phones if p.word == word_index]
            if not own:
                raise VispeechError(f"alignment failed: word {_ALTERNATE.sub('', name)!r} lies outside the audio")
            words.append(Word(_ALTERNATE.sub("", name), own[0].start, own[-1].end))
    if phones and phones[-1].end < duration - TIME_TOLERANCE:
        phones.append(Phone(SILENCE, phones[-1].end, duration))
    return PhoneSequence(phones, "en", words).validate()
