"""Audio front ends: pocketsphinx alignment of synthetic speech (dither, wide-beam retry, the
phone-pass fallback), DTW alignment against espeak-ng (its warping path librosa's), phone
recognition, and bad input.

Tolerances are the measured errors with headroom: DTW of espeak-ng's Swedish at rate 0.8
against its rate 1.0 lands phone starts a median 3 ms (at most 11 ms) from espeak's own; DTW
of GRID's bbaf2n puts every word boundary within 50 ms of the corpus's; recognition of bbaf2n
has a phone error rate of 0.50 against the forced alignment.
"""

import numpy as np
import pytest
import soundfile

import vispeech.frontends.align as align_module
from vispeech import VispeechError
from vispeech.alignment.formats import read_alignment, read_word_alignment
from vispeech.frontends.align import align, normalize_transcript
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.dtw_align import warping_path
from vispeech.frontends.espeak import synthesize
from vispeech.frontends.recognize import match_phones, recognize_phones
from vispeech.phonetics.inventory import get_inventory

MOM = "My mom made a large map of the farm."
SWEDISH = "Hej, vi möts på bron i morgon."


@pytest.fixture
def bbaf2n(grid_s1):
    folder = grid_s1 / "utterances"
    samples, rate = soundfile.read(folder / "bbaf2n.flac", dtype="float32")
    return samples, rate, "bin blue at f two now", read_word_alignment(folder / "bbaf2n.align")


def _check_covers(phones, duration):
    """Validated, gap-free, from 0 to the end of the audio, words made of their own phones."""
    phones.validate()
    assert phones.phones[0].start == 0.0 and phones.duration == pytest.approx(duration, abs=1e-6)
    for before, after in zip(phones.phones, phones.phones[1:], strict=False):
        assert after.start == pytest.approx(before.end, abs=1e-6)
    for index, word in enumerate(phones.words):
        own = [p for p in phones if p.word == index]
        assert own and own[0].start == pytest.approx(word.start) and own[-1].end == pytest.approx(word.end)


@pytest.mark.parametrize("rate", [1.0, 2.5])  # 2.5: only the wide-beam retry finds a path
def test_synthetic_speech_aligns_with_its_bilabials_inside_their_words(rate):
    speech = synthesize(MOM, "en", rate)
    phones = align(speech.audio, speech.sample_rate, MOM)
    _check_covers(phones, speech.duration)
    assert [w.text for w in phones.words] == normalize_transcript(MOM)
    starts = [w.start for w in phones.words]
    assert starts == sorted(starts) and all(w.end <= speech.duration for w in phones.words)
    by_word = {w.text: [p.symbol for p in phones if p.word == i] for i, w in enumerate(phones.words)}
    assert by_word["my"][0] == "M" and by_word["mom"] == ["M", "AA", "M"] and by_word["made"][0] == "M"
    assert by_word["map"] == ["M", "AE", "P"]
    # espeak's own word times, up to "map" (espeak runs "of the" together)
    for aligned, spoken in zip(phones.words[:6], speech.phones.words[:6], strict=True):
        assert abs(aligned.start - spoken.start) <= 0.05, (aligned, spoken)


def test_pocketsphinx_alignment_is_deterministic():
    speech = synthesize(MOM, "en")
    first = align(speech.audio, speech.sample_rate, MOM)
    assert align(speech.audio, speech.sample_rate, MOM) == first


def test_cli_aligns_what_say_wrote(tmp_path):
    from click.testing import CliRunner

    from vispeech.cli import main

    runner = CliRunner()
    said = runner.invoke(main, ["say", MOM, "-o", str(tmp_path / "mom")])
    assert said.exit_code == 0, said.output
    out = tmp_path / "mom.TextGrid"
    result = runner.invoke(main, ["align", str(tmp_path / "mom" / "speech.wav"), MOM, "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert [w.text for w in read_alignment(out, language="en").words] == normalize_transcript(MOM)


def test_a_failed_phone_pass_shares_each_word_among_its_phones(bbaf2n, monkeypatch):
    samples, rate, text, reference = bbaf2n

    def fail(decoder, raw):
        raise RuntimeError("Failed to stop utterance processing")

    monkeypatch.setattr(align_module, "_phone_pass", fail)
    # align's own work, in this process where the patch holds (align runs it in a worker process)
    phones = align_module._pocketsphinx_align(AudioClip.from_array(samples, rate), text, None)
    _check_covers(phones, len(samples) / rate)
    assert phones.symbols == ["sil", "B", "IH", "N", "B", "L", "UW", "AE", "T", "EH", "F", "T", "UW", "N", "AW", "sil"]
    for aligned, ref in zip(phones.words, reference, strict=True):  # the word pass is unchanged
        assert abs(aligned.start - ref.start) <= 0.06 and abs(aligned.end - ref.end) <= 0.06
    for index, word in enumerate(phones.words):  # equal shares, to the 10 ms frame
        durations = [p.duration for p in phones if p.word == index]
        assert max(durations) - min(durations) <= 0.0100001, (word, durations)


def test_swedish_dtw_recovers_espeaks_own_boundaries_at_another_rate():
    recording = synthesize(SWEDISH, "sv", rate=0.8)  # the reference inside align speaks at 1.0
    phones = align(recording.audio, recording.sample_rate, SWEDISH, "sv")
    assert phones.language == "sv"
    _check_covers(phones, recording.duration)
    assert phones.symbols == recording.phones.symbols
    assert [w.text for w in phones.words] == ["Hej", "vi", "möts", "på", "bron", "i", "morgon"]
    errors = np.abs(phones.starts - recording.phones.starts)[1:]
    assert np.median(errors) <= 0.010 and errors.max() <= 0.025, errors


def test_dtw_leading_silence_does_not_stretch_the_first_phone():
    recording = synthesize(SWEDISH, "sv", rate=0.8)
    second = np.zeros(recording.sample_rate, dtype=np.float32)
    noise = np.random.default_rng(0).normal(0.0, 3e-3, recording.sample_rate).astype(np.float32)
    for lead in (second, noise):
        audio = np.concatenate([lead, recording.audio])
        phones = align(audio, recording.sample_rate, SWEDISH, "sv")
        _check_covers(phones, len(audio) / recording.sample_rate)
        spoken, truth = phones.phones[1], recording.phones.phones[1]
        assert phones.phones[0].symbol == "sil" and phones.phones[0].end == pytest.approx(spoken.start)
        assert abs(spoken.start - (truth.start + 1.0)) <= 0.015
        assert abs(spoken.duration - truth.duration) <= 0.02


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (6, 1), (2, 3), (40, 55), (210, 180)])
def test_warping_path_is_librosas(shape):
    """The same path as ``librosa.sequence.dtw`` (as alignment was tuned with), ties included:
    on costs in [0, 1) and on costs rounded to tenths, where many paths cost the same."""
    import librosa

    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    for cost in (rng.random(shape), np.round(rng.random(shape), 1)):
        np.testing.assert_array_equal(warping_path(cost), librosa.sequence.dtw(C=cost)[1])


def test_warping_path_of_speech_at_two_rates_is_librosas():
    """On the cosine distances of log-mel frames, as :func:`dtw_align` warps them."""
    import librosa

    from vispeech.frontends.dtw_align import _features

    slow, fast = (synthesize(SWEDISH, "sv", rate=r) for r in (0.8, 1.0))
    frames = [_features(AudioClip.from_array(u.audio, u.sample_rate).resampled(16000).samples) for u in (slow, fast)]
    units = [f / np.linalg.norm(f, axis=1, keepdims=True) for f in frames]
    cost = 1.0 - units[1] @ units[0].T
    path = warping_path(cost)
    np.testing.assert_array_equal(path, librosa.sequence.dtw(C=cost)[1])
    assert len(path) >= max(cost.shape) and tuple(path[-1]) == (0, 0)


def test_english_dtw_finds_grid_word_boundaries(bbaf2n):
    samples, rate, text, reference = bbaf2n
    phones = align(samples, rate, text, "en", method="dtw")
    _check_covers(phones, len(samples) / rate)
    assert [w.text for w in phones.words] == text.split()
    assert set(phones.symbols) <= set(get_inventory("en").symbols)
    for aligned, ref in zip(phones.words, reference, strict=True):
        assert abs(aligned.start - ref.start) <= 0.08 and abs(aligned.end - ref.end) <= 0.08, (aligned, ref)


def test_recognition_hears_most_of_a_grid_utterance(bbaf2n):
    samples, rate, text, _ = bbaf2n
    heard = recognize_phones(samples, rate)
    _check_covers(heard, len(samples) / rate)
    assert heard.words == [] and heard.language == "en"
    assert set(heard.symbols) <= set(get_inventory("en").symbols)
    assert heard.phones[0].symbol == "sil" and heard.phones[0].end >= 0.3  # the corpus's first word starts at 0.95 s
    aligned = align(samples, rate, text)
    edits, pairs = match_phones(aligned, heard)
    assert edits / sum(not p.is_silence for p in aligned) <= 0.65
    assert len(pairs) >= 6 and np.median([abs(a.start - h.start) for a, h in pairs]) <= 0.02
    assert recognize_phones(samples, rate) == heard


def test_match_phones_counts_edits_and_pairs_equal_phones():
    from vispeech.alignment.phones import Phone, PhoneSequence

    def sequence(symbols):
        return PhoneSequence([Phone(s, i * 0.1, (i + 1) * 0.1) for i, s in enumerate(symbols.split())], "en")

    edits, pairs = match_phones(sequence("sil B IH N sil"), sequence("B IY N N"))
    assert edits == 2 and [(r.symbol, h.symbol) for r, h in pairs] == [("B", "B"), ("N", "N")]
    assert match_phones(sequence("B IH N"), sequence("sil")) == (3, [])


def test_alignment_that_cannot_succeed_says_where(bbaf2n):
    samples, rate, text, _ = bbaf2n
    with pytest.raises(VispeechError, match=r"too short for the 14 phones"):
        align(samples[int(0.9 * rate):int(1.25 * rate)], rate, text)
    with pytest.raises(VispeechError, match=r"no path through the audio from word 20 of 24 \('blue'\) on"):
        align(samples, rate, " ".join([text] * 4))  # 2.98 s hold 56 phones, but not this sentence four times


@pytest.mark.parametrize("call", [
    lambda audio, rate: align(audio, rate, "hello"),
    lambda audio, rate: align(audio, rate, "hej", "sv"),
    lambda audio, rate: recognize_phones(audio, rate),
], ids=["pocketsphinx", "dtw", "recognize"])
def test_bad_audio_is_refused_in_one_line(call):
    with pytest.raises(VispeechError, match="silent"):
        call(np.zeros(16000, dtype=np.float32), 16000)
    with pytest.raises(VispeechError, match="no speech"):
        call(np.random.default_rng(0).normal(0.0, 0.05, 16000).astype(np.float32), 16000)
    with pytest.raises(VispeechError, match="non-finite"):
        call(np.full(16000, np.nan, dtype=np.float32), 16000)
    with pytest.raises(VispeechError, match="empty"):
        call(np.zeros(0, dtype=np.float32), 16000)


def test_bad_text_language_or_method_is_refused():
    speech = synthesize(SWEDISH, "sv")
    with pytest.raises(VispeechError, match="text is empty"):
        align(speech.audio, speech.sample_rate, "  ", "sv")
    with pytest.raises(VispeechError, match="no words"):
        align(speech.audio, speech.sample_rate, " ... ")
    with pytest.raises(VispeechError, match="unknown language 'xx'"):
        align(speech.audio, speech.sample_rate, "hello", "xx")
    with pytest.raises(VispeechError, match="English only"):
        align(speech.audio, speech.sample_rate, SWEDISH, "sv", method="pocketsphinx")
    with pytest.raises(VispeechError, match="unknown alignment method 'hmm'"):
        align(speech.audio, speech.sample_rate, SWEDISH, "sv", method="hmm")
