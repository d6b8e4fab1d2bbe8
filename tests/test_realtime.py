"""A voice service's timings into phones (:mod:`vispeech.frontends.timings`) and the engine that
animates them as they arrive with the audio (:class:`vispeech.realtime.TimedSpeechStream`)."""

from __future__ import annotations

import numpy as np
import pytest

from vispeech.alignment.phones import Word
from vispeech.errors import VispeechError
from vispeech.frontends.audio import to_pcm16
from vispeech.frontends.espeak import synthesize
from vispeech.frontends.timings import (
    OCULUS_PHONES,
    characters_to_words,
    phones_over_visemes,
    phones_over_words,
    timed_word_phones,
    viseme_phone,
)
from vispeech.models.registry import load_model
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.motion.formats.visemes import OCULUS_VISEMES
from vispeech.motion.track import Track
from vispeech.pipeline import animate, padded
from vispeech.postprocess.rest import SentFrames, rest_ease
from vispeech.realtime import TimedSpeechStream
from vispeech.streaming import STREAM_CHANNELS

SENTENCE = "Please bring my map back by noon."
BILABIALS = ("P", "B", "M")


@pytest.fixture(scope="module")
def model():
    return load_model("grid-tdnn-lowlatency")


@pytest.fixture(scope="module")
def speech():
    """espeak-ng's :data:`SENTENCE` between the silences ``speak`` puts around speech: its words
    and their times are what a voice service would send with the audio."""
    return padded(synthesize(SENTENCE, "en"), 0.2, 0.25)


def offline(speech, model) -> np.ndarray:
    """What a stream of ``speech``'s word timings animates, offline."""
    phones = timed_word_phones(speech.phones.words, "en", speech.duration)
    return animate(phones, model).select(STREAM_CHANNELS).values


def characters_of(words: list[Word]) -> list[tuple[str, float, float]]:
    """The characters of ``words`` as ElevenLabs times them: each word's span shared among its
    letters, a space between words."""
    out: list[tuple[str, float, float]] = []
    for k, word in enumerate(words):
        if k:
            out.append((" ", out[-1][2], word.start))
        step = (word.end - word.start) / len(word.text)
        out += [(c, word.start + i * step, word.start + (i + 1) * step) for i, c in enumerate(word.text)]
    return out


def run(stream: TimedSpeechStream, steps) -> np.ndarray:
    """Push ``steps`` (``("audio", bytes)`` or ``(kind, args)``) in order, then finish: every frame, in order."""
    rows, expected = [], 0
    for kind, args in steps:
        push = {"audio": stream.push, "words": stream.add_words, "characters": stream.add_characters,
                "visemes": stream.add_visemes}[kind]
        start, frames = push(args) if kind in ("audio", "words", "visemes") else push(*args)
        assert start == expected
        rows.append(frames)
        expected += len(frames)
    start, frames = stream.finish()
    assert start == expected
    return np.concatenate(rows + [frames])


def closed_on_bilabials(frames: np.ndarray, phones, fps: float = 30.0) -> list[bool]:
    aperture = lip_aperture(Track(frames, STREAM_CHANNELS, fps))
    return [aperture[max(0, int(p.start * fps) - 1):int(np.ceil(p.end * fps)) + 1].min() <= LIP_CLOSED
            for p in phones if p.symbol in BILABIALS]


def test_words_become_phones_over_their_spans():
    sequence = timed_word_phones([Word("map,", 0.3, 0.6), Word("—", 0.6, 0.7), Word("by", 0.8, 1.0)], "en", 1.2)
    phones = sequence.phones
    assert [p.symbol for p in phones] == ["sil", "M", "AE", "P", "sil", "B", "AY", "sil"]
    assert (phones[1].start, phones[3].end, phones[5].start, phones[6].end) == (0.3, 0.6, 0.8, 1.0)
    assert sequence.duration == 1.2
    # a word starting before the one before it ends starts there; one ending there is refused
    assert phones_over_words([Word("map", 0.3, 0.6), Word("by", 0.55, 0.9)], "en")[4].start == 0.6
    with pytest.raises(VispeechError, match="before the words before it end"):
        phones_over_words([Word("map", 0.3, 0.6), Word("by", 0.2, 0.5)], "en")


def test_characters_become_words_at_white_space():
    words = characters_to_words(list("Hi, Bob! "), [0.1 * k for k in range(9)], [0.1 * k + 0.1 for k in range(9)])
    assert words == [Word("Hi,", 0.0, 0.30000000000000004), Word("Bob!", 0.4, 0.8)]
    with pytest.raises(VispeechError, match="as many"):
        characters_to_words(["a", "b"], [0.0], [0.1, 0.2])


def test_visemes_read_as_the_phones_they_show():
    assert set(OCULUS_PHONES) == set(OCULUS_VISEMES)
    assert viseme_phone(21) == ("P", 0) and viseme_phone("PP") == ("P", 0) and viseme_phone("viseme_aa") == ("AA", 1)
    assert viseme_phone(0) == viseme_phone("sil") == ("sil", 0)
    for bad in (22, -1, "pp", "21", True):
        with pytest.raises(VispeechError, match="unknown viseme"):
            viseme_phone(bad)
    phones = phones_over_visemes([(0, 0.0), (21, 0.2), ("aa", 0.3)], 0.5)
    assert [(p.symbol, p.start, p.end) for p in phones] == [("sil", 0.0, 0.2), ("P", 0.2, 0.3), ("AA", 0.3, 0.5)]


def test_word_timings_stream_as_animate_animates_them_and_close_the_lips(model, speech):
    words = speech.phones.words
    pcm = to_pcm16(speech.audio).tobytes()
    stream = TimedSpeechStream(model, "words", speech.sample_rate)
    assert stream.channels == STREAM_CHANNELS and stream.lookahead == 3
    third = len(pcm) // 6 * 2
    # the first words come before their audio, the last after it
    frames = run(stream, [("words", words[:3]), ("audio", pcm[:third]), ("audio", pcm[third:2 * third]),
                          ("words", words[3:5]), ("audio", pcm[2 * third:]), ("words", words[5:])])
    reference = offline(speech, model)
    assert frames.shape == reference.shape == (speech.phones.n_frames(30.0), len(STREAM_CHANNELS))
    jaw = STREAM_CHANNELS.index("jawOpen")
    assert np.abs(frames[:, jaw] - reference[:, jaw]).max() < 0.02
    phones = timed_word_phones(words, "en", speech.duration)
    assert sum(p.symbol in BILABIALS for p in phones) == 7
    assert all(closed_on_bilabials(frames, phones))


def test_frames_wait_for_the_timings_and_come_ahead_of_the_audio(model, speech):
    words = speech.phones.words
    stream = TimedSpeechStream(model, "words", speech.sample_rate)
    assert len(stream.push(to_pcm16(speech.audio).tobytes())[1]) == 0  # audio alone: no frames yet
    start, frames = stream.add_words(words[:2])
    assert start == 0 and len(frames) == int(words[1].end * 30) + 1 - stream.lookahead
    early = TimedSpeechStream(model, "words", speech.sample_rate)  # no audio at all yet
    assert np.allclose(early.add_words(words[:2])[1], frames)


def test_characters_split_inside_words_give_the_frames_of_the_words(model, speech):
    """Post-processing works on a window of the frames given so far, so pieces differ a little
    from the whole in the channels it sets (mouthClose, the tongue), never in the model's jaw."""
    chars = characters_of(speech.phones.words)
    stream = TimedSpeechStream(model, "characters", speech.sample_rate)
    pieces = [chars[k:k + 7] for k in range(0, len(chars), 7)]  # messages end inside words
    steps = [("characters", tuple(map(list, zip(*piece)))) for piece in pieces]
    frames = run(stream, [("audio", to_pcm16(speech.audio).tobytes()), *steps])
    reference = offline(speech, model)
    jaw = STREAM_CHANNELS.index("jawOpen")
    assert np.abs(frames[:, jaw] - reference[:, jaw]).max() < 1e-6
    assert np.abs(frames - reference).mean() < 0.002


def test_visemes_close_the_lips_on_bilabials(model):
    stream = TimedSpeechStream(model, "visemes", 16000)
    stream.push(bytes(2 * 16000))  # 1 s of audio
    visemes = [(0, 0.0), (21, 0.2), (2, 0.3), (21, 0.5), (1, 0.6), (0, 0.75)]
    frames = run(stream, [("visemes", visemes[:3]), ("visemes", visemes[3:])])
    assert len(frames) == 30
    phones = phones_over_visemes(visemes, 1.0)
    assert all(closed_on_bilabials(frames, phones))
    assert lip_aperture(Track(frames, STREAM_CHANNELS, 30.0))[int(0.4 * 30)] > 2 * LIP_CLOSED  # /a/ opens
    with pytest.raises(VispeechError, match="comes before"):
        TimedSpeechStream(model, "visemes", 16000).add_visemes([(0, 0.5), (21, 0.2)])


def test_bad_timings_are_refused_and_the_stream_goes_on(model, speech):
    words = speech.phones.words
    stream = TimedSpeechStream(model, "words", speech.sample_rate)
    stream.add_words(words[:2])
    with pytest.raises(VispeechError, match="not characters"):
        stream.add_characters(["a"], [0.0], [0.1])
    with pytest.raises(VispeechError, match="before the words before it end"):
        stream.add_words([words[0]])
    assert stream.add_words(words[2:3])[0] > 0
    with pytest.raises(VispeechError, match="unknown timings"):
        TimedSpeechStream(model, "phones", 16000)
    with pytest.raises(VispeechError, match="sample rate"):
        TimedSpeechStream(model, "words", 100)


def test_a_cancel_eases_the_face_to_rest_at_once(model, speech):
    stream = TimedSpeechStream(model, "words", speech.sample_rate)
    start, frames = stream.add_words(speech.phones.words[:3])
    start, ease = stream.cancel()
    assert start == len(frames) and len(ease) == 3 and stream.closed
    jaw = STREAM_CHANNELS.index("jawOpen")
    assert frames[-1, jaw] > ease[0, jaw] > ease[1, jaw] > 0 and not ease[-1].any()
    with pytest.raises(VispeechError, match="has ended"):
        stream.add_words(speech.phones.words[3:4])
    assert rest_ease(np.ones(4), 60.0).shape == (6, 4)
    # after the stream ended, from the frame a client shows
    ended = TimedSpeechStream(model, "words", speech.sample_rate)
    frames = run(ended, [("audio", to_pcm16(speech.audio).tobytes()), ("words", speech.phones.words)])
    start, ease = ended.cancel(30)
    assert start == 31 and np.allclose(ease[0] / ease[0, jaw], frames[30] / frames[30, jaw], atol=1e-6)
    assert ended.cancel(10_000)[0] == len(frames)


@pytest.mark.parametrize(("language", "word", "phone_set"), [("sv", "mamma", "sv"), ("de", "Mutter", "ipa")])
def test_words_of_other_languages_are_read_in_their_phones(model, language, word, phone_set):
    stream = TimedSpeechStream(model, "words", 16000, language)
    stream.push(bytes(2 * 16000))
    frames = run(stream, [("words", [Word(word, 0.3, 0.7)])])
    phones = timed_word_phones([Word(word, 0.3, 0.7)], language, 1.0)
    assert phones.language == phone_set and phones.phones[1].symbol == "m" and len(frames) == 30
    aperture = lip_aperture(Track(frames, STREAM_CHANNELS, 30.0))
    assert aperture[int(phones.phones[1].start * 30):int(phones.phones[1].end * 30) + 2].min() <= LIP_CLOSED


def test_a_pause_longer_than_a_phone_streams_step_is_taken(model):
    stream = TimedSpeechStream(model, "words", 16000)
    stream.push(bytes(2 * 16000 * 30))  # 30 s of audio
    frames = run(stream, [("words", [Word("map", 0.3, 0.6)]), ("words", [Word("by", 21.0, 21.3)])])
    assert len(frames) == 900 and stream.duration == 30.0
    aperture = lip_aperture(Track(frames, STREAM_CHANNELS, 30.0))
    assert aperture[int(21.0 * 30)] <= LIP_CLOSED and np.abs(frames[10 * 30]).max() < 1e-3  # /b/ closed; rest between


def test_a_stream_keeps_the_last_two_minutes_of_frames_to_ease_from():
    sent = SentFrames(2, 30.0)
    assert sent.ease(5)[0] == 0  # nothing given yet: the ease starts at frame 0
    for k in range(13):  # 130 s in 10-s chunks, frame k's values (k, -k)
        rows = np.arange(k * 300, (k + 1) * 300, dtype=float)
        sent.add(np.stack([rows, -rows], axis=1))
    assert sent.count == 3900
    start, ease = sent.ease(2100)
    assert start == 2101 and len(ease) == 3 and np.allclose(ease[0] / ease[0, 0], [1.0, -1.0]) and ease[0, 0] < 2100
    assert sent.ease(0)[0] == 301  # older than two minutes: from the oldest frame kept
    assert sent.ease()[0] == sent.ease(5000)[0] == 3900
