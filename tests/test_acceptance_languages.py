"""Issue 14 acceptance: one sentence in each of 20 languages, and every voice espeak-ng ships."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.signal import find_peaks

from conftest import DATA
from vispeech.alignment.phones import Phone
from vispeech.evaluation.closures import is_bilabial, phone_frames
from vispeech.frontends.espeak import PhoneWarning, languages, synthesize
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.phonetics.inventory import is_vowel
from vispeech.pipeline import DEFAULT_MODEL, speak

MODELS = [DEFAULT_MODEL, "baseline"]
"""The shipped network (English data, feature input) and the rule baseline."""
SENTENCES = [tuple(line.split("\t")) for line in (DATA / "sentences_world.tsv").read_text(encoding="utf-8").splitlines()
             if line.strip() and not line.startswith("#")]
REQUIRED = {"de", "fr", "es", "it", "pt", "nl", "nb", "da", "fi", "pl", "ru", "el", "tr", "ar", "hi", "cmn", "ja",
            "ko", "sw", "id"}


@pytest.fixture(scope="module")
def utterances():
    """Every (language, model) spoken once, with any PhoneWarning an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhoneWarning)
        return {(lang, model): speak(text, lang, model=model) for lang, text in SENTENCES for model in MODELS}


def test_twenty_languages_across_families_and_scripts():
    assert {lang for lang, _ in SENTENCES} == REQUIRED


@pytest.mark.parametrize("model", MODELS)
def test_track_length_matches_audio(utterances, model):
    for lang, _ in SENTENCES:
        utt = utterances[lang, model]
        assert utt.phones.language == "ipa"
        audio_frames = len(utt.audio) / utt.sample_rate * utt.track.fps
        assert abs(utt.track.n_frames - audio_frames) <= 1, lang


@pytest.mark.parametrize("model", MODELS)
def test_every_bilabial_closes(utterances, model):
    checked = 0
    for lang, _ in SENTENCES:
        utt = utterances[lang, model]
        aperture = lip_aperture(utt.track)
        for phone in utt.phones:
            if is_bilabial(phone.symbol, "ipa"):
                frames = phone_frames(phone.start, phone.end, utt.track.fps, utt.track.n_frames, pad=0)
                assert aperture[frames].min() <= LIP_CLOSED, (lang, phone, aperture[frames])
                checked += 1
    assert checked >= 100


@pytest.mark.parametrize("model", MODELS)
def test_jaw_peaks_fall_inside_vowels(utterances, model):
    for lang, _ in SENTENCES:
        utt = utterances[lang, model]
        fps = utt.track.fps
        peaks, _ = find_peaks(utt.track["jawOpen"], prominence=0.02, height=0.05)
        assert len(peaks) > 0, lang
        vowels = [p for p in utt.phones if is_vowel(p.symbol, "ipa")]
        for k in peaks:
            assert any(v.start - 1 / fps <= k / fps <= v.end + 1 / fps for v in vowels), (lang, model, k / fps)


def test_every_language_speaks_numbers_without_unknown_phonemes():
    """Every language espeak-ng ships (with its dictionary) reads digits and letters into known phones
    (Cherokee, Chuvash and Sindarin have no number words)."""
    listed = languages()
    assert len(listed) > 100 and {"sv", "en", "de", "cmn"} <= {v.code for v in listed}
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhoneWarning)
        for language in listed:
            phones = synthesize("1 2 3 7 10, a b c", language.code).phones
            assert phones.language == language.phones, language
            assert any(not p.is_silence for p in phones), language
            assert phones.phones[-1].end == pytest.approx(phones.duration)


def test_text_and_phone_streams_in_any_language():
    from vispeech.models.registry import load_model
    from vispeech.streaming import open_phone_stream
    from vispeech.text_stream import speech_messages

    model = load_model(DEFAULT_MODEL)
    messages = [m for batch in speech_messages("Guten Tag. Wie geht es dir?", "de", model) for m in batch]
    frames = sum(len(m["frames"]) for m in messages if m["type"] == "frames")
    assert messages[0]["type"] == "start" and messages[-1]["type"] == "end"
    assert frames == messages[-1]["n_frames"] > 20
    stream = open_phone_stream(model, "ipa")
    timed = [("sil", 0.0, 0.1), ("m", 0.1, 0.2), ("ˈa", 0.2, 0.4), ("m", 0.4, 0.5), ("a", 0.5, 0.7), ("sil", 0.7, 0.9)]
    _, first = stream.push([Phone(s, a, b) for s, a, b in timed])
    _, rest = stream.finish()
    assert len(first) + len(rest) == 27


def test_cli_lists_languages_and_says_in_one(tmp_path):
    import json

    from click.testing import CliRunner

    from vispeech.alignment.formats import read_alignment
    from vispeech.cli import main

    listed = CliRunner().invoke(main, ["languages"])
    assert listed.exit_code == 0 and "German" in listed.output and "fr-fr" in listed.output
    table = json.loads(CliRunner().invoke(main, ["languages", "--json"]).output)
    assert {"language": "sv", "aliases": [], "phones": "sv", "name": "Swedish"} in table
    voices = json.loads(CliRunner().invoke(main, ["languages", "--voices", "--json"]).output)
    assert {"voice": "f3", "gender": "female"} in voices and {"voice": "m1", "gender": "male"} in voices
    said = CliRunner().invoke(main, ["say", "Mamma mia, che bella pizza!", "--language", "it", "-o", str(tmp_path / "it")])
    assert said.exit_code == 0, said.output
    phones = read_alignment(tmp_path / "it" / "phones.TextGrid")
    assert phones.language == "ipa" and [s for s in phones.symbols if s != "sil"][:2] == ["m", "a"]
    unknown = CliRunner().invoke(main, ["say", "hi", "--language", "xx", "-o", str(tmp_path / "xx")])
    assert unknown.exit_code == 2 and "unknown language 'xx'" in unknown.output
    assert not (tmp_path / "xx").exists()


@pytest.mark.parametrize(("symbol", "language", "viseme"), [
    ("P", "en", "PP"), ("M", "en", "PP"), ("F", "en", "FF"), ("TH", "en", "TH"), ("T", "en", "DD"), ("K", "en", "kk"),
    ("CH", "en", "CH"), ("SH", "en", "CH"), ("S", "en", "SS"), ("N", "en", "nn"), ("L", "en", "nn"), ("R", "en", "RR"),
    ("HH", "en", "kk"), ("W", "en", None), ("AA", "en", None), ("sil", "en", None), ("rs", "sv", "SS"),
    ("ɸ", "ipa", "PP"), ("ʋ", "ipa", "FF"), ("ʂ", "ipa", "SS"), ("ɕ", "ipa", "CH"), ("ŋ", "ipa", "nn"), ("ʁ", "ipa", "kk"),
    ("ɾ", "ipa", "RR"), ("ɭ", "ipa", "nn"), ("ʈ", "ipa", "DD"), ("ʔ", "ipa", "kk"), ("j", "ipa", None), ("aɪ", "ipa", None),
])
def test_oculus_visemes_of_consonants_come_from_their_features(symbol, language, viseme):
    from vispeech.motion.formats.visemes import oculus_viseme

    assert oculus_viseme(symbol, language) == viseme


@pytest.mark.parametrize("model", MODELS)
def test_viseme_exports_name_lip_consonants_in_every_language(utterances, model):
    """Oculus PP and Rhubarb A on every bilabial, FF and G on every labiodental; a pose alone
    would read closed lips as silence."""
    from vispeech.motion.formats.visemes import mouth_cues, oculus_visemes

    for lang, _ in SENTENCES:
        utt = utterances[lang, model]
        visemes = oculus_visemes(utt.track, phones=utt.phones)
        top = np.array(visemes.channels)[np.argmax(visemes.values, axis=1)]
        cues = mouth_cues(utt.track, phones=utt.phones)
        for phone in utt.phones:
            lips = {"PP": "A", "FF": "G"}.get(oculus_viseme_of(phone))
            if lips is None:
                continue
            frames = phone_frames(phone.start, phone.end, utt.track.fps, utt.track.n_frames, pad=0)
            assert {"PP": "A", "FF": "G"}[top[frames][0]] == lips, (lang, phone)
            start, end = phone.start - utt.track.start_time, phone.end - utt.track.start_time  # cues: the phone's time
            assert any(c.value == lips and c.start < end and c.end > start for c in cues), (lang, phone)


def oculus_viseme_of(phone) -> str | None:
    from vispeech.motion.formats.visemes import oculus_viseme

    return None if phone.is_silence else oculus_viseme(phone.symbol, "ipa")


def test_speech_in_any_language_aligns_by_dtw():
    """A transcript in German is aligned with German speech by DTW against espeak-ng: IPA phones."""
    from vispeech.frontends.align import align

    text = "Mein Bruder baut ein Boot am Meer."
    speech = synthesize(text, "de", rate=0.8)  # other timing than the reference DTW warps onto
    phones = align(speech.audio, speech.sample_rate, text, "de")
    assert phones.language == "ipa"
    assert [p.symbol for p in phones if not p.is_silence] == [p.symbol for p in speech.phones if not p.is_silence]
    assert [w.text for w in phones.words] == ["Mein", "Bruder", "baut", "ein", "Boot", "am", "Meer"]
    assert phones.duration == pytest.approx(speech.duration)
