"""Alignment files: TextGrid / HTK lab / GRID align / JSON round trips and their errors."""

import json

import pytest

from vispeech import Phone, PhoneSequence, VispeechError, Word
from vispeech.alignment.formats import read_alignment, read_word_alignment, write_alignment, write_textgrid


def english() -> PhoneSequence:
    phones = [
        Phone("sil", 0.0, 0.1), Phone("HH", 0.1, 0.17, 0), Phone("AH", 0.17, 0.25, 0, 0), Phone("L", 0.25, 0.3, 0),
        Phone("OW", 0.3, 0.45, 0, 1), Phone("sp", 0.45, 0.5), Phone("W", 0.5, 0.6, 1), Phone("ER", 0.6, 0.7, 1, 1),
        Phone("L", 0.7, 0.75, 1), Phone("D", 0.75, 0.8, 1), Phone("sil", 0.8, 1.0),
    ]
    return PhoneSequence(phones, "en", [Word("hello", 0.1, 0.45), Word("world", 0.5, 0.8)])


def swedish() -> PhoneSequence:
    phones = [
        Phone("sil", 0.0, 0.12), Phone("h", 0.12, 0.2, 0), Phone("E", 0.2, 0.31, 0, 1), Phone("j", 0.31, 0.4, 0),
        Phone("b", 0.4, 0.46, 1), Phone("u:", 0.46, 0.6, 1, 2), Phone("rd", 0.6, 0.7, 1), Phone("sil", 0.7, 0.9),
    ]
    return PhoneSequence(phones, "sv", [Word("hej", 0.12, 0.4), Word("bord", 0.4, 0.7)])


@pytest.mark.parametrize("make", [english, swedish])
@pytest.mark.parametrize("ext", ["TextGrid", "json"])
def test_round_trip_with_words(tmp_path, make, ext):
    phones = make()
    path = tmp_path / f"utt.{ext}"
    write_alignment(phones, path)
    assert read_alignment(path) == phones  # language guessed from the labels


@pytest.mark.parametrize("make", [english, swedish])
@pytest.mark.parametrize("ext,unit", [("lab", 1e-7), ("align", 1 / 25000)])
def test_round_trip_of_timed_labels(tmp_path, make, ext, unit):
    phones = make()
    path = tmp_path / f"utt.{ext}"
    write_alignment(phones, path)
    back = read_alignment(path)
    assert back.language == phones.language and back.words == []
    assert [(p.symbol, p.stress) for p in back] == [(p.symbol, p.stress) for p in phones]
    for a, b in zip(back, phones):
        assert abs(a.start - b.start) <= unit / 2 and abs(a.end - b.end) <= unit / 2


def test_lab_and_align_units(tmp_path):
    write_alignment(english(), tmp_path / "a.lab")
    write_alignment(english(), tmp_path / "a.align")
    assert (tmp_path / "a.lab").read_text().splitlines()[2] == "1700000 2500000 AH0"
    assert (tmp_path / "a.align").read_text().splitlines()[4] == "7500 11250 OW1"


def test_textgrid_layout_is_mfa_like(tmp_path):
    write_textgrid(english(), tmp_path / "a.TextGrid")
    text = (tmp_path / "a.TextGrid").read_text()
    assert text.index('name = "words"') < text.index('name = "phones"')
    assert 'text = "OW1"' in text and 'text = "hello"' in text


MFA_TEXTGRID = """File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 0.9
tiers? <exists>
size = 2
item []:
    item [1]:
        class = "IntervalTier"
        name = "Words"
        xmin = 0
        xmax = 0.9
        intervals: size = 3
        intervals [1]:
            xmin = 0
            xmax = 0.2
            text = ""
        intervals [2]:
            xmin = 0.2
            xmax = 0.6
            text = "bat"
        intervals [3]:
            xmin = 0.6
            xmax = 0.9
            text = ""
    item [2]:
        class = "IntervalTier"
        name = "PHONES"
        xmin = 0
        xmax = 0.9
        intervals: size = 5
        intervals [1]:
            xmin = 0
            xmax = 0.2
            text = ""
        intervals [2]:
            xmin = 0.2
            xmax = 0.3
            text = "b"
        intervals [3]:
            xmin = 0.3
            xmax = 0.5
            text = "ae1"
        intervals [4]:
            xmin = 0.5
            xmax = 0.6
            text = "T"
        intervals [5]:
            xmin = 0.6
            xmax = 0.9
            text = "spn"
"""


def test_reads_mfa_textgrid_with_empty_intervals_and_stress(tmp_path):
    path = tmp_path / "mfa.TextGrid"
    path.write_text(MFA_TEXTGRID)
    phones = read_alignment(path)
    assert phones.language == "en"
    assert [(p.symbol, p.stress, p.word) for p in phones] == [
        ("sil", 0, None), ("B", 0, 0), ("AE", 1, 0), ("T", 0, 0), ("sil", 0, None)]
    assert phones.words == [Word("bat", 0.2, 0.6)]
    assert phones.frame_labels(10) == ["sil", "sil", "B", "AE", "AE", "T", "sil", "sil", "sil"]


def test_lone_tier_is_the_phones_tier(tmp_path):
    path = tmp_path / "one.TextGrid"
    path.write_text(MFA_TEXTGRID.replace("size = 2", "size = 1").split("    item [2]:")[0]
                    .replace('"bat"', '"m"').replace('"Words"', '"segments"'))
    assert read_alignment(path, language="sv").symbols == ["sil", "m", "sil"]


def test_gaps_in_a_written_textgrid_read_back_as_silence(tmp_path):
    phones = PhoneSequence([Phone("m", 0.2, 0.3, 0), Phone("a", 0.35, 0.5, 0, 1)], "sv", [Word("ma", 0.2, 0.5)])
    write_alignment(phones, tmp_path / "gap.TextGrid")
    assert read_alignment(tmp_path / "gap.TextGrid") == phones.with_gaps_filled()


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(VispeechError, match="not found"):
        read_alignment(tmp_path / "nope.TextGrid")
    for name in ("empty.TextGrid", "empty.lab", "empty.json"):
        (tmp_path / name).write_text("  \n")
        with pytest.raises(VispeechError, match="empty"):
            read_alignment(tmp_path / name)


def test_malformed_textgrid_is_one_line(tmp_path):
    path = tmp_path / "bad.TextGrid"
    path.write_text('File type = "ooTextFile"\nObject class = "TextGrid"\n\nxmin = 0\nxmax = oops\n')
    with pytest.raises(VispeechError) as info:
        read_alignment(path)
    assert "bad.TextGrid" in str(info.value) and "\n" not in str(info.value)


def test_textgrid_without_phones_tier(tmp_path):
    path = tmp_path / "nophones.TextGrid"
    path.write_text(MFA_TEXTGRID.replace('"PHONES"', '"segments"'))
    with pytest.raises(VispeechError, match="no phones tier.*Words, segments"):
        read_alignment(path)


def test_unknown_symbol_names_symbol_and_file(tmp_path):
    path = tmp_path / "x.lab"
    path.write_text("0 1000000 sil\n1000000 2000000 AA1\n2000000 3000000 QQ\n")
    with pytest.raises(VispeechError, match=r"x\.lab.*'QQ'"):
        read_alignment(path)
    with pytest.raises(VispeechError, match=r"x\.lab.*'AA1'"):
        read_alignment(path, language="sv")


@pytest.mark.parametrize("body", ["0 2000 sil\n1000 3000 a\n", "2000 3000 a\n0 2000 sil\n", "0 2000 a\n2000 2000 b\n"])
def test_overlapping_unsorted_or_empty_intervals(tmp_path, body):
    path = tmp_path / "o.align"
    path.write_text(body)
    with pytest.raises(VispeechError, match="o.align"):
        read_alignment(path)


def test_bad_lines_and_extensions(tmp_path):
    (tmp_path / "t.lab").write_text("0 100 sil\nhello world\n")
    with pytest.raises(VispeechError, match="line 2"):
        read_alignment(tmp_path / "t.lab")
    with pytest.raises(VispeechError, match="unknown alignment format"):
        read_alignment(tmp_path / "t.txt")


def test_json_rejects_other_formats_and_stressed_symbols(tmp_path):
    data = {"format": "vispeech-phones", "version": 1, **english().to_dict()}
    data["phones"][4]["symbol"] = "OW1"
    (tmp_path / "a.json").write_text(json.dumps(data))
    with pytest.raises(VispeechError, match="'OW1' is not an inventory symbol"):
        read_alignment(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"format": "vispeech-animation"}))
    with pytest.raises(VispeechError, match="not a vispeech-phones file"):
        read_alignment(tmp_path / "b.json")


@pytest.mark.parametrize("stress", [7, -3, 3])
def test_stress_is_0_1_or_2(tmp_path, stress):
    data = {"format": "vispeech-phones", "version": 1, **english().to_dict()}
    data["phones"][4]["stress"] = stress
    (tmp_path / "a.json").write_text(json.dumps(data))
    with pytest.raises(VispeechError, match=rf"a.json: phone 4 \(OW\) has stress {stress}; stress is 0, 1 or 2$"):
        read_alignment(tmp_path / "a.json")
    phones = english()
    phones.phones[4] = Phone("OW", 0.3, 0.45, 0, stress)
    with pytest.raises(VispeechError, match="stress is 0, 1 or 2"):
        write_alignment(phones, tmp_path / "a.TextGrid")
    assert not (tmp_path / "a.TextGrid").exists()


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "keep.TextGrid"
    write_alignment(english(), path)
    before = path.read_bytes()
    with pytest.raises(VispeechError):
        write_alignment(PhoneSequence([], "en"), path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["keep.TextGrid"]


def test_grid_word_alignment(shared_dir):
    words = read_word_alignment(shared_dir / "data/grid_s1/utterances/bbaf2n.align")
    assert [w.text for w in words] == ["bin", "blue", "at", "f", "two", "now"]
    assert words[0].start == pytest.approx(23750 / 25000) and words[-1].end == pytest.approx(53000 / 25000)
    with pytest.raises(VispeechError, match="'bin'"):
        read_alignment(shared_dir / "data/grid_s1/utterances/bbaf2n.align")


def test_an_empty_pause_is_dropped_and_an_empty_phone_refused(tmp_path):
    # pocketsphinx's word alignments (dev_eval/natural) can end on a pause of no length
    (tmp_path / "words.align").write_text("0 2500 sil\n2500 10000 bin\n10000 12500 sil\n12500 12500 sil\n")
    words = read_word_alignment(tmp_path / "words.align")
    assert [(w.text, w.start, w.end) for w in words] == [("bin", 0.1, 0.4)]
    (tmp_path / "phones.lab").write_text("0 1000000 sil\n1000000 1000000 sp\n1000000 2000000 AH1\n2000000 2000000 AH1\n")
    with pytest.raises(VispeechError, match="line 4: the span ends at 2000000, not after its start"):
        read_alignment(tmp_path / "phones.lab")


@pytest.mark.parametrize("name", ["a.TextGrid", "a.json", "a.lab"])
def test_an_alignment_its_reader_would_refuse_is_not_written(name, tmp_path):
    """Found by the API's QA: write_alignment wrote unknown symbols ("XYZ") and languages
    ("klingon") into every format, files read_alignment then refused."""
    from vispeech.alignment.formats import read_alignment, write_alignment

    for phones, message in ((PhoneSequence([Phone("sil", 0, 0.1), Phone("XYZ", 0.1, 0.3)], "en"),
                             "phone 1 at 0.100 s: unknown phone symbol 'XYZ' for language en"),
                            (PhoneSequence([Phone("sil", 0, 0.1), Phone("AH", 0.1, 0.3)], "klingon"),
                             "unknown language 'klingon'")):
        with pytest.raises(VispeechError, match=f"^cannot write {tmp_path / name}: .*{message}"):
            write_alignment(phones, tmp_path / name)
        assert not (tmp_path / name).exists()
    good = PhoneSequence([Phone("sil", 0, 0.1), Phone("AH", 0.1, 0.3, None, 1)], "en")
    write_alignment(good, tmp_path / name)
    assert [p.symbol for p in read_alignment(tmp_path / name, language="en")] == ["sil", "AH"]
