"""One utterance end to end: text, phones or audio → control model → post-processing → output files.

The CLI (``say``, ``animate``, ``animate-phones``) and the server are thin layers over these calls.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vispeech.alignment.formats import write_textgrid
from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_dir, check_output_dir, write_output_dirs
from vispeech.frontends.audio import AudioClip
from vispeech.limits import check_fps, check_text, check_utterance
from vispeech.models.contract import Estimator
from vispeech.models.registry import load_model
from vispeech.motion.formats.registry import ALIASES, livelink_texts, write_track
from vispeech.motion.rigging.calibration import Calibration, load_scale
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import SILENCE
from vispeech.postprocess import AUTO, NONE, Postprocessing, postprocess, postprocessing_config
from vispeech.utterance import Utterance

if TYPE_CHECKING:
    from vispeech.frontends.espeak import Speech

DEFAULT_FPS = 30.0
DEFAULT_SCALE = "arkit"
"""The output scale files are written in: ARKit's (docs/calibration.md); ``tracker`` keeps the
models' own scale, a calibration file fits one head."""
DEFAULT_MODEL = "grid-tdnn"
"""The shipped network trained on GRID (``vispeech/models/pretrained``), for every language."""
DEFAULT_AUDIO_MODEL = "grid-audio-encdec"
"""The core install's audio network for recorded audio coming without a transcript: the
log-mel encoder-decoder, the best of the two on GRID's validation split (jawOpen r 0.865
against 0.819). :func:`default_audio_model` prefers :data:`WHISPER_AUDIO_MODEL`."""
WHISPER_AUDIO_MODEL = "grid-audio-whisper"
"""The audio network on Whisper's encoder (the ``whisper`` extra): on other people's voices and
faces jawOpen r 0.78 against 0.65 (another GRID speaker) and 0.30 against 0.20 (TV and web
speech), docs/audio.md."""
WHISPER_SWEDISH_MODEL = "grid-audio-whisper-base"
"""The same recipe on Whisper base's multilingual encoder, read after 4 of its 6 layers: tiny.en
never heard Swedish, and on espeak-ng's Swedish voices this one agrees better with the phone
model (mean pooled r 0.464 against 0.370), docs/audio.md."""
WHISPER_ENSEMBLE_MODEL = "grid-audio-whisper-ensemble"
"""The mean of :data:`WHISPER_AUDIO_MODEL`, :data:`WHISPER_SWEDISH_MODEL` and
:data:`DEFAULT_AUDIO_STREAM_MODEL` (:class:`~vispeech.models.ensemble.AudioEnsemble`):
better than any of them on grid_s1's validation split (jawOpen r 0.888 against 0.880, 0.884
and 0.819) and on espeak-ng's English and Swedish voices (mean pooled r 0.575 against 0.461
and 0.524 for the two Whisper models), docs/audio.md."""


def default_audio_model(language: str = "en") -> str:
    """The audio model that animates a recording in ``language`` by default: where both Whisper
    models are installed (:func:`vispeech.frontends.whisper.installed`),
    :data:`WHISPER_ENSEMBLE_MODEL` in every language; where one Whisper folder replaces both
    (``$VISPEECH_WHISPER_MODEL``) or only one is installed, :data:`WHISPER_SWEDISH_MODEL` for
    Swedish (``sv``, where Whisper base is) and :data:`WHISPER_AUDIO_MODEL` for every other
    language; else :data:`DEFAULT_AUDIO_MODEL`."""
    from vispeech.frontends.whisper import MODEL_ENV, installed

    if installed() and installed("whisper-base") and not os.environ.get(MODEL_ENV):
        return WHISPER_ENSEMBLE_MODEL
    if language == "sv" and installed("whisper-base"):
        return WHISPER_SWEDISH_MODEL
    return WHISPER_AUDIO_MODEL if installed() else DEFAULT_AUDIO_MODEL


def recording_model(transcript: bool, language: str = "en") -> str:
    """The model that animates a recording in ``language`` by default: without its ``transcript``,
    :func:`default_audio_model`; with an English one, :data:`WHISPER_AUDIO_MODEL` where Whisper is
    installed (its frames blended with the phones', :func:`blend_with_phones`: the best on every
    English corpus measured, docs/audio.md; :data:`WHISPER_ENSEMBLE_MODEL` scores 0.889 against
    0.885 on validation so, but costs a batch line a third more), else :data:`DEFAULT_MODEL` on
    the phones. Whisper tiny.en's features carry less of other languages, whose aligned phones
    say more."""
    from vispeech.frontends.whisper import installed

    if not transcript:
        return default_audio_model(language)
    return WHISPER_AUDIO_MODEL if language == "en" and installed() else DEFAULT_MODEL


DEFAULT_AUDIO_STREAM_MODEL = "grid-audio-cnn"
"""The shipped audio network for live audio: its stream equals its offline output, 126 ms behind."""
GREETINGS = {
    "sv": "Hej! Hur kan jag hjälpa dig idag?",
    "en": "Hello, how can I help you today?",
}
"""What ``vispeech say`` speaks when given no text."""
MAX_OUTPUT_SAMPLE_RATE = 48_000
"""The highest sample rate (Hz) of the audio :func:`listen` keeps; faster input is resampled to it."""


def animate(
    phones: PhoneSequence,
    model: str | Estimator = DEFAULT_MODEL,
    fps: float = DEFAULT_FPS,
    postprocessing: Postprocessing = AUTO,
) -> Track:
    """Animation for a time-aligned phone sequence at ``fps`` frames per second.

    ``model`` is a model name (see :data:`vispeech.models.registry.RUNNABLE`), a saved
    model folder or a model object; ``postprocessing`` is a configuration, a preset name,
    ``"auto"`` for the preset the model recommends
    (:attr:`~vispeech.models.contract.Estimator.postprocessing`) or ``"none"``
    (:data:`vispeech.postprocess.Postprocessing`).
    """
    check_fps(fps)
    _expect(phones, PhoneSequence, "animate takes phones (a PhoneSequence; audio: animate_audio or listen)")
    return _animate(phones, model, fps, postprocessing)


def _expect(value: object, kind: type, what: str) -> None:
    """Refuse ``value`` unless it is a ``kind``, saying ``what`` the function takes."""
    if not isinstance(value, kind):
        raise VispeechError(f"{what}, not {type(value).__name__}")


def _animate(
    phones: PhoneSequence,
    model: str | Estimator,
    fps: float,
    postprocessing: Postprocessing,
    speech: list[tuple[float, float]] | None = None,
) -> Track:
    """:func:`animate` at an ``fps`` already checked; ``speech``: where the audio's loudness shows
    speech, if there is audio (:func:`speech_spans`)."""
    phones.validate()
    check_utterance(phones.duration, len(phones))
    estimator = model if isinstance(model, Estimator) else load_model(model)
    return _postprocessed(estimator.predict(phones, fps), phones, postprocessing, estimator.postprocessing, speech)


def animate_many(
    phones: Sequence[PhoneSequence],
    model: str | Estimator = DEFAULT_MODEL,
    fps: float = DEFAULT_FPS,
    postprocessing: Postprocessing = AUTO,
) -> list[Track | VispeechError]:
    """:func:`animate` of each phone sequence, the same tracks, the model run on all of them at
    once (:meth:`~vispeech.models.contract.Estimator.predict_many`: ``grid-tdnn``'s kernels and
    recurrence step every utterance together) and the post-processing's settings made once.

    Returns, per sequence, its track or the :class:`VispeechError` that refused it (phones out of
    order, over a limit, in a language the model does not take); the others are animated all the
    same. Made for many short utterances: a game's lines, a corpus (README, "Python").
    """
    check_fps(fps)
    estimator = model if isinstance(model, Estimator) else load_model(model)
    config = postprocessing_config(postprocessing, estimator.postprocessing)
    results: dict[int, Track | VispeechError] = {}
    checked = []
    for i, sequence in enumerate(phones):
        try:
            _expect(sequence, PhoneSequence, f"utterance {i}: animate_many takes phones (PhoneSequences)")
            sequence.validate()
            check_utterance(sequence.duration, len(sequence))
            checked.append(i)
        except VispeechError as exc:
            results[i] = exc
    for i, track in zip(checked, _predicted(estimator, [phones[i] for i in checked], fps)):
        if config is not None and isinstance(track, Track):
            try:
                track = postprocess(track, phones[i], config)
            except VispeechError as exc:
                track = exc
        results[i] = track
    return [results[i] for i in range(len(phones))]


def _predicted(estimator: Estimator, phones: list[PhoneSequence], fps: float) -> list[Track | VispeechError]:
    """The model's tracks of ``phones``, all at once; where it refuses one, each alone, so that
    the error is that sequence's."""
    try:
        return list(estimator.predict_many(phones, fps))
    except VispeechError:
        results: list[Track | VispeechError] = []
        for sequence in phones:
            try:
                results.append(estimator.predict(sequence, fps))
            except VispeechError as exc:
                results.append(exc)
        return results


def animate_audio(
    clip: AudioClip,
    model: str | Estimator = DEFAULT_AUDIO_MODEL,
    fps: float = DEFAULT_FPS,
    postprocessing: Postprocessing = AUTO,
    phones: PhoneSequence | None = None,
) -> Track:
    """Animation of speech audio at ``fps``, ``clip.n_frames(fps)`` frames from time 0.

    An audio model (``input_kind == "audio"``) animates the audio itself; a phone model
    animates ``phones``, which must then be given (the audio's alignment). Post-processing
    as in :func:`animate`; an audio model's recommended preset (``audio``) needs no phones;
    with ``phones`` given its output is blended with :data:`DEFAULT_MODEL`'s animation of them
    (:func:`blend_with_phones`) and gets the ``audio-closures`` preset's closures on them, and
    without, a model that hears bilabials (:meth:`~vispeech.models.contract.Estimator.predict_with_closures`)
    gets the ``audio-closures`` preset's closures on them. The mouth rests where the audio is quiet
    (:func:`speech_spans`).
    """
    check_fps(fps)
    _expect(clip, AudioClip, "animate_audio takes audio (an AudioClip: AudioClip.read or AudioClip.from_array)")
    return _animate_audio(clip, model, fps, postprocessing, phones)


def _animate_audio(
    clip: AudioClip,
    model: str | Estimator,
    fps: float,
    postprocessing: Postprocessing,
    phones: PhoneSequence | None,
) -> Track:
    """:func:`animate_audio` at an ``fps`` already checked."""
    check_utterance(clip.duration, 0 if phones is None else len(phones))
    estimator = model if isinstance(model, Estimator) else load_model(model)
    speech = None if postprocessing == NONE else speech_spans(clip)
    if estimator.input_kind != "audio":
        if phones is None:
            raise VispeechError(f"model {estimator.name} animates phones: give the transcript to align the audio with")
        return _animate(phones, estimator, fps, postprocessing, speech).resample(fps, n_frames=clip.n_frames(fps))
    if phones is not None:
        track = blend_with_phones(estimator.predict(clip, fps), _raw_phone_track(phones, fps, clip.n_frames(fps)))
        return _postprocessed(track, phones, postprocessing, "audio-closures", speech)
    track, heard = estimator.predict_with_closures(clip, fps)
    preset = estimator.postprocessing if heard is None else "audio-closures"
    return _postprocessed(track, heard, postprocessing, preset, speech)


LOUDNESS_ONSET_MARGIN = 0.15
"""Seconds of speech that a clip's loudness misses before its first loud frame: the silent
closure of a first stop, a soft first sound. On grid_s1's train split the loudness span starts
after the first word's timing in 10 % of the utterances, by at most 0.157 s in 99 %."""
LOUDNESS_OFFSET_MARGIN = 0.1
"""Seconds of speech that a clip's loudness misses after its last loud frame (a fading last
sound): on grid_s1's train split the span ends at most 0.12 s before the last word in 99 %."""


AUDIO_WEIGHT = 0.7
"""An audio model's share of the frames when the transcript's phones are known as well
(:func:`blend_with_phones`); the rest is :data:`DEFAULT_MODEL`'s animation of the phones. Chosen
on grid_s1's validation split for :data:`WHISPER_AUDIO_MODEL` (jawOpen r 0.863 from the phones
alone, 0.886 from the audio alone, 0.891 at 0.7; 0.5 to 0.8 are within 0.002); docs/audio.md."""


def blend_with_phones(audio: Track, phones: Track, audio_weight: float = AUDIO_WEIGHT) -> Track:
    """An audio model's ``audio`` track with a phone model's ``phones`` track of the same frames
    mixed in: ``audio_weight`` of the first and the rest of the second on the channels both have;
    the audio model's own frames on the others. The sound carries how this speaker moves, the
    phones what was said: each corrects the other's errors (docs/audio.md)."""
    if audio.n_frames != phones.n_frames:
        raise ValueError(f"the tracks differ in length: {audio.n_frames} and {phones.n_frames} frames")
    values = audio.values.copy()
    for j, channel in enumerate(audio.channels):
        if channel in phones.channels:
            values[:, j] = audio_weight * values[:, j] + (1.0 - audio_weight) * phones[channel]
    return Track(values, audio.channels, audio.fps, audio.start_time)


def _raw_phone_track(phones: PhoneSequence, fps: float, n_frames: int) -> Track:
    """:data:`DEFAULT_MODEL`'s animation of ``phones``, not post-processed, ``n_frames`` long."""
    phones.validate()
    return _default_phone_model().predict(phones, fps).resample(fps, n_frames=n_frames)


@functools.cache
def _default_phone_model() -> Estimator:
    """:data:`DEFAULT_MODEL`, loaded once per process (19 ms a load) for every blend."""
    return load_model(DEFAULT_MODEL)


def speech_openness(clip: AudioClip, language: str = "en", model: Estimator | None = None) -> np.ndarray:
    """How open the jaw is through ``clip`` as the best audio model for ``language`` hears it
    (:func:`default_audio_model`, its raw jawOpen; ``model``: that model loaded already), at
    :data:`~vispeech.corpus.av_sync.ANALYSIS_RATE` from the clip's start: the sound's own
    timing, to which :func:`~vispeech.corpus.av_sync.openness_offset` syncs a captured picture."""
    from vispeech.corpus.av_sync import ANALYSIS_RATE

    model = load_model(default_audio_model(language)) if model is None else model
    return model.predict(clip, ANALYSIS_RATE).select(["jawOpen"]).values[:, 0]


def speech_spans(clip: AudioClip) -> list[tuple[float, float]]:
    """Where ``clip``'s loudness shows speech: its one span from the first to the last speech frame
    (:func:`~vispeech.frontends.activity.speech_span`, so an audible breath before the first word
    counts), widened by what loudness misses (:data:`LOUDNESS_ONSET_MARGIN`,
    :data:`LOUDNESS_OFFSET_MARGIN`) within the clip; none for a clip that is silent or steady noise."""
    from vispeech.frontends.activity import speech_span

    try:
        start, end = speech_span(clip)
    except VispeechError:
        return []
    return [(max(0.0, start - LOUDNESS_ONSET_MARGIN), min(clip.duration, end + LOUDNESS_OFFSET_MARGIN))]


def _postprocessed(
    track: Track,
    phones: PhoneSequence | None,
    postprocessing: Postprocessing,
    preset: str,
    speech: list[tuple[float, float]] | None = None,
) -> Track:
    """``track`` post-processed by ``postprocessing``, with ``preset`` the one ``"auto"`` stands for;
    the mouth resting away from ``speech`` if given, else from the phones that are not silence."""
    config = postprocessing_config(postprocessing, preset)
    return track if config is None else postprocess(track, phones, config, speech=speech)


def speak(
    text: str,
    language: str = "en",
    *,
    model: str | Estimator = DEFAULT_MODEL,
    rate: float = 1.0,
    fps: float = DEFAULT_FPS,
    postprocessing: Postprocessing = AUTO,
    voice: str | None = None,
) -> Utterance:
    """Synthesise ``text`` with espeak-ng and animate it: audio, phones and a track of equal length.

    What is spoken is :func:`vispeech.frontends.text.speakable` of ``text`` (no Markdown markup,
    links or emoji), and that is the utterance's ``text``. ``voice`` is one of
    :func:`vispeech.frontends.espeak.voices` (an avatar's voice; ``None``: the language's own).
    """
    check_fps(fps)
    utterance = utter(text, language, rate=rate, voice=voice)
    assert utterance.phones is not None  # utter() gives espeak-ng's phones
    return replace(utterance, track=_animate(utterance.phones, model, fps, postprocessing))


LEADING_SILENCE = 0.2
"""Seconds of silence :func:`utter` puts before espeak-ng's speech, which starts with the first
sound: the time the mouth takes to open from rest (post-processing's rest in silence), so that
the first frame shows it at rest. A whole number of frames at 25, 30, 50 and 60 fps, so that the
frames fall on the phones where they fell without it."""
TRAILING_SILENCE = 0.25
"""Seconds of silence :func:`utter` adds after espeak-ng's speech, which ends with the last
sound: the time the mouth takes to come back to rest, so that a player holding the last frame
shows a closed mouth."""


def utter(text: str, language: str = "en", *, rate: float = 1.0, voice: str | None = None) -> Utterance:
    """The first half of :func:`speak`: the utterance without a track, what of ``text`` is
    spoken (:func:`spoken_text`) with espeak-ng's audio and phones, between
    :data:`LEADING_SILENCE` and :data:`TRAILING_SILENCE` (:func:`padded`)."""
    from vispeech.frontends.espeak import synthesize

    check_text(text)
    spoken = spoken_text(text)
    speech = padded(synthesize(spoken, language, rate=rate, voice=voice), LEADING_SILENCE, TRAILING_SILENCE)
    return Utterance(text=spoken, phones=speech.phones, audio=speech.audio, sample_rate=speech.sample_rate)


def padded(speech: Speech, before: float, after: float) -> Speech:
    """``speech`` with ``before`` seconds of silence put before it and ``after`` added after it, in
    its audio and its phones: every time moved by ``before``, the first and last silence phones
    lengthened to the ends (or silence phones added)."""
    rate = speech.sample_rate
    lead, trail = round(before * rate), round(after * rate)
    audio = np.concatenate([np.zeros(lead, speech.audio.dtype), speech.audio, np.zeros(trail, speech.audio.dtype)])
    sequence = speech.phones.shifted(lead / rate)
    phones = list(sequence.phones)
    if lead and phones[0].is_silence:
        phones[0] = replace(phones[0], start=0.0)
    elif lead:
        phones.insert(0, Phone(SILENCE, 0.0, lead / rate))
    end = len(audio) / rate
    if phones[-1].is_silence:
        phones[-1] = replace(phones[-1], end=end)
    elif trail:
        phones.append(Phone(SILENCE, phones[-1].end, end))
    return replace(speech, audio=audio, phones=replace(sequence, phones=phones))


def spoken_text(text: str) -> str:
    """What of ``text`` is spoken (:func:`~vispeech.frontends.text.speakable`); :class:`VispeechError`
    when nothing is left."""
    from vispeech.frontends.text import speakable

    spoken = speakable(text)
    if not any(character.isalnum() for character in spoken):  # "...", a zero-width space: nothing either
        raise VispeechError(
            "text is empty"
            if not text.strip()
            else "nothing to say: the text has no words once emoji, markup and links are left out"
        )
    return spoken


def listen(
    clip: AudioClip,
    text: str | None = None,
    language: str = "en",
    *,
    model: str | Estimator | None = None,
    fps: float = DEFAULT_FPS,
    postprocessing: Postprocessing = AUTO,
    force: bool = False,
) -> Utterance:
    """Animate recorded speech: audio, text, phones (``None`` without ``text``) and a track of
    ``clip.n_frames(fps)`` frames from time 0.

    Without ``text`` an audio model animates the audio. With ``text`` the transcript is aligned
    with the audio in ``language`` (:func:`vispeech.frontends.align.align`) and a model of
    either kind animates it with those phones: a phone model the phones, an audio model the
    audio blended with the phones (:func:`blend_with_phones`). The default model is
    :func:`recording_model`'s. A recording without its transcript gets one
    from :func:`vispeech.frontends.transcribe.transcribe` (the ``whisper`` extra):
    ``listen(clip, transcribe(clip, language), language)``. The utterance keeps the clip's
    audio at its own sample rate, or at :data:`MAX_OUTPUT_SAMPLE_RATE` if that is faster. An
    English transcript that does not fit the audio is refused (``force``: taken all the same).
    """
    check_fps(fps)
    utterance = hear(clip, text, language, force=force)
    default = recording_model(utterance.phones is not None, language)
    track = _animate_audio(clip, default if model is None else model, fps, postprocessing, utterance.phones)
    return replace(utterance, track=track)


def hear(clip: AudioClip, text: str | None = None, language: str = "en", *, force: bool = False) -> Utterance:
    """The first half of :func:`listen`: the recording's utterance without a track, its audio at
    most :data:`MAX_OUTPUT_SAMPLE_RATE` and, with ``text``, the transcript's aligned phones
    (:class:`~vispeech.frontends.align.TranscriptMismatch` for an English transcript whose fit
    is below :data:`~vispeech.frontends.align.MIN_FIT`, unless ``force`` or Whisper hears it:
    :func:`~vispeech.frontends.transcribe.second_opinion`, with the ``whisper`` extra)."""
    _expect(clip, AudioClip, "a recording is audio (an AudioClip: AudioClip.read or AudioClip.from_array)")
    phones = None
    if text is not None:
        from vispeech.frontends.align import MIN_FIT, TranscriptMismatch, align
        from vispeech.frontends.transcribe import second_opinion

        check_text(text)
        try:
            phones = align(clip.samples, clip.sample_rate, text, language, min_fit=None if force else MIN_FIT)
        except TranscriptMismatch as mismatch:
            agrees, heard = second_opinion(clip, text)
            if not agrees:
                said = (
                    f" Whisper heard {heard[:80]!r}." if heard else "" if heard is None else " Whisper heard no words."
                )
                raise TranscriptMismatch(f"{mismatch}{said}") from None
            phones = align(clip.samples, clip.sample_rate, text, language)
    audio = clip.resampled(min(clip.sample_rate, MAX_OUTPUT_SAMPLE_RATE))
    return Utterance(text=text or "", phones=phones, audio=audio.samples, sample_rate=audio.sample_rate)


OUTPUT_FILES: dict[str, str] = {
    "wav": "speech.wav",
    "textgrid": "phones.TextGrid",
    "livelink": "animation.csv",
    "json": "animation.json",
    "preview": "preview.html",
    "oculus": "animation.visemes.csv",
    "rhubarb": "mouth_cues.tsv",
    "talkinghead": "animation.talkinghead.json",
}
"""What :func:`write_outputs` can write: format name → file name (the audio, the phones, the
preview page, and tracks in the formats of :data:`vispeech.motion.formats.registry.FORMATS`:
Live Link Face CSV, vispeech JSON, Oculus viseme curves, Rhubarb mouth cues, TalkingHead JSON;
see docs/formats.md). A track format's aliases (``csv``) are accepted too."""
DEFAULT_OUTPUTS: tuple[str, ...] = ("wav", "textgrid", "livelink", "json", "preview")
"""The formats ``say``, ``animate`` and ``animate-phones`` write (those the utterance has data for)."""
AUDIO_OUTPUTS: tuple[str, ...] = ("wav", "textgrid", "preview")
"""The formats :func:`write_outputs` writes only for an utterance with audio (the TextGrid with it:
an alignment read from a file is not written back)."""


def check_formats(formats: Iterable[str]) -> tuple[str, ...]:
    """``formats`` as a tuple of names of :data:`OUTPUT_FILES` (aliases replaced by the names);
    :class:`VispeechError` names any other."""
    formats = tuple(ALIASES.get(f, f) for f in formats)
    unknown = [f for f in formats if f not in OUTPUT_FILES]
    if unknown or not formats:
        what = f"unknown output format {unknown[0]!r}" if unknown else "no output format given"
        raise VispeechError(f"{what} (use {', '.join(OUTPUT_FILES)})")
    return formats


def check_outputs(out_dir: str | Path, *, extra: Iterable[str] = (), inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Refuse now an output folder :func:`write_outputs` would refuse after the work (one holding
    a user's files, a file, a read-only folder: :func:`vispeech.files.check_output_dir`), or one
    that holds any of the work's ``inputs`` (the swap would remove them)."""
    check_output_dir(out_dir, replaces=(*OUTPUT_FILES.values(), *extra), inputs=inputs)


def write_outputs(
    utterance: Utterance,
    out_dir: str | Path,
    *,
    title: str | None = None,
    formats: Iterable[str] = DEFAULT_OUTPUTS,
    extra: Mapping[str, str] | None = None,
    scale: str | os.PathLike | None = DEFAULT_SCALE,
) -> list[Path]:
    """Write an utterance's files as the folder ``out_dir`` and return their paths.

    The track is written in the output ``scale`` (:func:`vispeech.motion.rigging.calibration.load_scale`:
    ``arkit``, ``tracker`` or a calibration file).

    ``formats`` names the files (:data:`OUTPUT_FILES`); by default ``animation.csv`` (Live Link
    Face) and ``animation.json``, with audio also ``speech.wav`` and ``preview.html``, and
    ``phones.TextGrid`` when it has phones too: a format the utterance has no data for (audio,
    phones) is left out. ``extra`` adds text files (name → content), e.g. a batch's record of
    the line. The folder is written whole beside ``out_dir`` and swapped in with one rename
    (:func:`vispeech.files.atomic_output_dir`), so it never holds files of two runs: phones
    written into a folder ``say`` made leave no old wav, TextGrid or preview behind. An
    existing ``out_dir`` is replaced only when it holds nothing but files these calls write;
    any other file in it (a folder of the user's) stops the run with :class:`VispeechError`,
    and so does a path that is not a folder.
    """
    formats = check_formats(formats)
    utterance = _scaled(utterance, load_scale(scale))
    extra = dict(extra or {})
    with atomic_output_dir(out_dir, replaces=(*OUTPUT_FILES.values(), *extra)) as staging:
        names = _write_files(utterance, staging, formats, title, extra)
    return [Path(out_dir) / n for n in names]


def write_outputs_many(
    utterances: Sequence[Utterance],
    out_dirs: Sequence[str | Path],
    *,
    formats: Iterable[str] = DEFAULT_OUTPUTS,
    scale: str | os.PathLike | None = DEFAULT_SCALE,
) -> list[list[Path] | VispeechError]:
    """:func:`write_outputs` of ``utterances[i]`` into ``out_dirs[i]`` for every i: the same files
    and the same promise for each folder (old or new, whole), the files of all the folders made
    durable together before any is swapped in (:func:`vispeech.files.write_output_dirs`: one
    sync of their file system where the system has one, instead of an fsync a file).

    Returns, per utterance, its files' paths or the :class:`VispeechError` that stopped it (a
    folder of the user's, a track out of range): that folder is left as it was, the others are
    written all the same.
    """
    if len(utterances) != len(out_dirs):
        raise ValueError(f"{len(utterances)} utterances for {len(out_dirs)} folders")
    formats = check_formats(formats)
    calibration = load_scale(scale)
    scaled = [_scaled(utterance, calibration) for utterance in utterances]
    tracks = [u.track for u in scaled if u.track is not None] if "livelink" in formats else []
    texts = iter(livelink_texts(tracks))  # every CSV formatted at once
    csv = [next(texts) if "livelink" in formats and u.track is not None else None for u in scaled]
    names: list[list[str]] = [[] for _ in utterances]

    def write(i: int, staging: Path) -> None:
        text = csv[i]
        if isinstance(text, VispeechError):
            raise text
        names[i] = _write_files(scaled[i], staging, formats, None, {}, {} if text is None else {"livelink": text})

    errors = write_output_dirs(out_dirs, write, replaces=OUTPUT_FILES.values())
    return [error or [Path(out) / n for n in written] for error, out, written in zip(errors, out_dirs, names)]


def _scaled(utterance: Utterance, calibration: Calibration | None) -> Utterance:
    """``utterance`` with its track in the output scale of ``calibration`` (``None``: as it is)."""
    if calibration is None or utterance.track is None:
        return utterance
    return replace(utterance, track=calibration.apply(utterance.track))


def _write_files(
    utterance: Utterance,
    staging: Path,
    formats: tuple[str, ...],
    title: str | None,
    extra: Mapping[str, str],
    made: Mapping[str, bytes] | None = None,
) -> list[str]:
    """Write the files of :func:`write_outputs` into the folder ``staging``, those of ``made``
    (format name → bytes) as they are; their names."""
    from vispeech.preview import render_preview

    names: list[str] = []
    wav = utterance.wav_bytes()
    for fmt in OUTPUT_FILES:
        name = OUTPUT_FILES[fmt]
        if fmt not in formats or (wav is None and fmt in AUDIO_OUTPUTS):
            continue
        if made and fmt in made:
            (staging / name).write_bytes(made[fmt])
        elif fmt == "wav":
            assert wav is not None  # skipped above when None
            (staging / name).write_bytes(wav)
        elif fmt == "textgrid":
            if utterance.phones is None:
                continue
            write_textgrid(utterance.phones, staging / name)
        elif fmt == "preview":
            assert utterance.track is not None  # the track formats need the track
            html = render_preview(utterance.track, utterance.phones, wav, title or utterance.text or "vispeech")
            (staging / name).write_text(html, encoding="utf-8")
        else:
            assert utterance.track is not None
            write_track(utterance.track, staging / name, fmt, phones=utterance.phones)
        names.append(name)
    for name, text in extra.items():
        (staging / name).write_text(text, encoding="utf-8")
        names.append(name)
    return names
