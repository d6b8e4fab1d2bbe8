"""Forced alignment with pocketsphinx, against GRID's own word timings; ``vispeech align``."""

import numpy as np
import pytest
import soundfile
from click.testing import CliRunner
from scipy.signal import resample_poly

from vispeech import VispeechError
from vispeech.alignment.formats import read_alignment, read_word_alignment
from vispeech.cli import main
from vispeech.frontends.align import align, normalize_transcript
from vispeech.phonetics.inventory import get_inventory

TEXT = "bin blue at f two now"


@pytest.fixture
def grid_utterance(grid_s1):
    folder = grid_s1 / "utterances"
    return folder / "bbaf2n.flac", read_word_alignment(folder / "bbaf2n.align")


def test_alignment_matches_grid_word_timings(grid_utterance):
    path, reference = grid_utterance
    samples, rate = soundfile.read(path)
    phones = align(samples, rate, "Bin blue at F two now.")
    assert phones.language == "en"
    assert [w.text for w in phones.words] == TEXT.split() == [w.text for w in reference]
    for aligned, ref in zip(phones.words, reference, strict=True):
        assert abs(aligned.start - ref.start) <= 0.060, (aligned, ref)
        assert abs(aligned.end - ref.end) <= 0.060, (aligned, ref)
    assert phones.symbols == ["sil", "B", "IH", "N", "B", "L", "UW", "AE", "T", "EH", "F", "T", "UW", "N", "AW", "sil"]
    assert phones.phones[0].start == 0.0 and phones.duration == pytest.approx(len(samples) / rate)
    assert set(phones.symbols) <= set(get_inventory("en").symbols)
    for p in phones:  # every phone inside its word; silences belong to none
        if p.is_silence:
            assert p.word is None
        else:
            word = phones.words[p.word]
            assert word.start - 1e-9 <= p.start < p.end <= word.end + 1e-9


def test_alignment_resamples_and_mixes_down(grid_utterance):
    path, _ = grid_utterance
    samples, rate = soundfile.read(path)
    stereo = np.column_stack([resample_poly(samples, 441, 160)] * 2)  # 44.1 kHz, two channels
    direct = align(samples, rate, TEXT)
    resampled = align(stereo, 44100, TEXT)
    starts = np.array([w.start for w in resampled.words])
    np.testing.assert_allclose(starts, [w.start for w in direct.words], atol=0.03)
    assert resampled.duration == pytest.approx(direct.duration, abs=1e-3)


def test_alignment_refuses_bad_input():
    audio = np.zeros(16000)
    with pytest.raises(VispeechError, match="zqxw, 42"):
        align(audio, 16000, "hello zqxw world 42 zqxw")
    with pytest.raises(VispeechError, match="English only"):
        align(audio, 16000, "hej", language="sv", method="pocketsphinx")
    with pytest.raises(VispeechError, match="no words"):
        align(audio, 16000, " ... ")
    with pytest.raises(VispeechError, match="empty"):
        align(np.zeros(0), 16000, "hello")
    assert normalize_transcript("“Hello,” she said—don't!") == ["hello", "she", "said—don't"]


def test_cli_align_writes_a_textgrid(grid_utterance, tmp_path):
    path, reference = grid_utterance
    out = tmp_path / "out" / "bbaf2n.TextGrid"
    result = CliRunner().invoke(main, ["align", str(path), TEXT, "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "6 words" in result.output
    phones = read_alignment(out, language="en")
    assert [w.text for w in phones.words] == TEXT.split()
    assert abs(phones.words[0].start - reference[0].start) <= 0.06


@pytest.mark.parametrize("audio_name,text,message", [
    ("absent.wav", TEXT, "not found"),
    ("bbaf2n.flac", "bin blue at f 2 now", "pronouncing dictionary: 2"),
])
def test_cli_align_errors_in_one_line(grid_utterance, tmp_path, audio_name, text, message):
    path, _ = grid_utterance
    audio = path if audio_name == path.name else tmp_path / audio_name
    out = tmp_path / "x.TextGrid"
    result = CliRunner().invoke(main, ["align", str(audio), text, "-o", str(out)])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], result.output
    assert not out.exists()


def test_a_transcript_that_does_not_fit_the_audio_is_refused(grid_s1):
    """Five grid_s1 utterances: each one's own transcript fits (taken with the least fit asked for),
    the next one's does not (refused), and min_fit=None takes any."""
    from vispeech.frontends.align import MIN_FIT, TranscriptMismatch, transcript_fit
    from vispeech.frontends.audio import AudioClip

    texts = dict(line.split("\t") for line in (grid_s1 / "sentences.tsv").read_text().splitlines()[1:])
    ids = sorted(texts)[::180][:5]
    for name, other in zip(ids, ids[1:] + ids[:1]):
        clip = AudioClip.read(grid_s1 / "utterances" / f"{name}.flac")
        phones = align(clip.samples, clip.sample_rate, texts[name], min_fit=MIN_FIT)
        assert [w.text for w in phones.words] == texts[name].split()
        with pytest.raises(TranscriptMismatch, match="does not fit the audio"):
            align(clip.samples, clip.sample_rate, texts[other], min_fit=MIN_FIT)
        assert transcript_fit(clip, texts[other]) < MIN_FIT <= transcript_fit(clip, texts[name])
    forced = align(clip.samples, clip.sample_rate, texts[other])
    assert [w.text for w in forced.words] == texts[other].split()


def test_a_piece_of_a_recording_is_aligned_on_the_whole_s_frames(grid_s1):
    """transcript_fit's phone loop hears only the words' span: decoded with the cepstral mean of the
    whole recording, a piece of it gives the words where the whole did, scored alike (the mean fit
    is a difference of such scores); normalised by its own mean, as pocketsphinx would, its scores
    move by several units, as much as the fits of true transcripts spread."""
    from vispeech.frontends import align as aligner
    from vispeech.frontends.audio import AudioClip

    clip = AudioClip.read(grid_s1 / "utterances" / "bbaf2n.flac")
    raw = aligner.padded_pcm(clip)
    whole, realigner = aligner._decoder(), aligner._realigner()
    found = aligner._word_pass(whole, raw, TEXT.split())
    aligner._phone_pass(whole, raw)
    mean = whole.get_cmn()
    words = [(name, first) for name, first, _ in found if not name.startswith(("<", "["))]
    end = found[-1][1] if found[-1][0].startswith(("<", "[")) else found[-1][2] + 1
    first = words[0][1]
    scores = aligner._frame_scores(whole, end)[first:end]
    start = first - 30
    piece = raw[start * aligner._FRAME_BYTES : (end + 30) * aligner._FRAME_BYTES + aligner._WINDOW_BYTES]
    shift = {}
    for whole_mean in (mean, None):
        in_piece = aligner._word_pass(realigner, piece, TEXT.split(), whole_mean)
        starts = [a + start for name, a, _ in in_piece if not name.startswith(("<", "["))]
        assert len(starts) == len(words)
        if whole_mean:
            assert max(abs(a - b) for a, (_, b) in zip(starts, words, strict=True)) <= 1
        aligner._phone_pass(realigner, piece, whole_mean)
        in_span = aligner._frame_scores(realigner, end - start)[first - start :]
        shift[whole_mean is not None] = np.mean(in_span) - np.mean(scores)
    assert abs(shift[True]) < 2.0 and abs(shift[False]) > 4.0, shift


@pytest.mark.parametrize("name,wrong", [("bgauzp", "lay green at z seven soon"),
                                        ("pgbk7s", "place green with e eight please")])
def test_a_transcript_wrong_in_some_words_is_refused(grid_s1, name, wrong):
    """GRID's commands share their structure, so another command's transcript fits the audio in
    part: these two (held-out pairs of benchmarks/bench_transcript_fit.py) fit about -6.5 against
    a phone loop that weighs its language model as for words, and were taken."""
    from vispeech.frontends.align import MIN_FIT, TranscriptMismatch
    from vispeech.frontends.audio import AudioClip

    texts = dict(line.split("\t") for line in (grid_s1 / "sentences.tsv").read_text().splitlines()[1:])
    clip = AudioClip.read(grid_s1 / "utterances" / f"{name}.flac")
    phones = align(clip.samples, clip.sample_rate, texts[name], min_fit=MIN_FIT)
    assert [w.text for w in phones.words] == texts[name].split()
    with pytest.raises(TranscriptMismatch, match="does not fit the audio"):
        align(clip.samples, clip.sample_rate, wrong, min_fit=MIN_FIT)
