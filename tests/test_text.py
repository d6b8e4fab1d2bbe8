"""What of a text is spoken: Markdown's words without markup, no links, no emoji; plain text as it was."""

import pytest

from conftest import read_sentences
from test_cli_say import assert_clean_error, run
from vispeech.errors import VispeechError
from vispeech.frontends.text import Clause, ClauseReader, speakable, split_clauses
from vispeech.pipeline import speak


@pytest.mark.parametrize("lang", ["en", "sv"])
def test_plain_sentences_are_spoken_as_written(lang):
    for sentence in read_sentences(lang):
        assert speakable(sentence) == sentence
    for sentence in ("It costs 3.50 or 1,000 kronor.", "5 * 3 = 15, and 2 < 3 & 4 > 1.", "snake_case stays.",
                     "Hej!\nHur mår du ... ?"):
        assert speakable(sentence) == " ".join(sentence.split())


@pytest.mark.parametrize("text,spoken", [
    ("Hej 🙂! Hur mår du? 👍🏽", "Hej! Hur mår du?"),
    ("Family: 👨‍👩‍👧 ✔️ done 🎉", "Family: done"),
    ("**Sure!** See [the docs](https://example.org/docs) or https://vispeech.org/x, or www.example.org.",
     "Sure! See the docs or, or."),
    ("Steps:\n\n1. Open the file\n2. Save it\n\n```python\nprint(1)\n```\nDone", "Steps: Open the file. Save it. Done"),
    ("# Opening hours\nWe open at *nine* and close at __five__.", "Opening hours. We open at nine and close at five."),
    ("Use `vispeech say` now. ![logo](logo.png)", "Use vispeech say now."),
    ("> A quote<br>with a break", "A quote with a break"),
    ("Hello\x07 there\x1b[1;31m now\x1b[0m.", "Hello there now."),  # a terminal's bell and colours
])
def test_markup_links_and_emoji_are_not_spoken(text, spoken):
    assert speakable(text) == spoken


def test_nothing_to_say_is_one_error(tmp_path):
    for text in ("🙂 👍", "\x01\x02", "...", "\u200b", "?!"):
        with pytest.raises(VispeechError, match="nothing to say"):
            speak(text, "en")
    result = run("say", "🙂", "-o", str(tmp_path / "out"))
    assert_clean_error(result)
    assert "nothing to say" in result.output and not (tmp_path / "out").exists()


def test_say_speaks_the_words_and_writes_them(tmp_path):
    from vispeech.alignment.formats import read_alignment

    result = run("say", "**Hello** 🙂, see [our page](https://example.org)!", "-o", str(tmp_path / "out"))
    assert result.exit_code == 0, result.output
    phones = read_alignment(tmp_path / "out" / "phones.TextGrid", "en")
    assert [w.text for w in phones.words] == ["Hello", "see", "our", "page"]


def test_detect_language_names_a_language_only_when_sure():
    from vispeech.frontends.text import detect_language

    assert detect_language("What is your name?", ["sv", "en"]) == "en"
    assert detect_language("Vad heter du?", ["sv", "en"]) == "sv"
    assert detect_language("ok", ["sv", "en"]) is None  # too short to tell
    assert detect_language("Guten Tag, wie geht es Ihnen heute?", ["sv", "en", "de", "fr"]) == "de"
    assert detect_language("Guten Tag, wie geht es Ihnen heute?", ["sv", "cmn"]) in (None, "sv")
    assert detect_language("妈妈买了一本书，我们一起去看看吧。", ["en", "cmn"]) == "cmn"  # langid's zh


def test_a_streamed_text_gives_each_clause_once_a_letter_follows_it():
    """Fed a token at a time, the reader gives the clauses split_clauses gives the whole text, each as
    soon as a letter or digit follows its break; a fenced code block is left out."""
    text = "Sure, 3.5 kr! Here is code:\n\n```python\nprint(1, 2)\n```\n\nDet är bra ... ? Hej då 😀"
    reader, given = ClauseReader(), []
    for i, ch in enumerate(text):
        given += [(clause, text[: i + 1]) for clause in reader.feed(ch)]
    last = reader.finish()
    assert [c for c, _ in given] == [Clause("Sure,", False), Clause("3.5 kr!", True), Clause("Here is code:", True),
                                     Clause("Det är bra ... ?", True)]
    assert [seen[-1] for _, seen in given] == ["3", "H", "D", "H"]  # the first letter or digit after the break
    assert last == [Clause("Hej då 😀", True)]  # the text's end ends its sentence
    assert [c.text for c, _ in given] + [c.text for c in last] == split_clauses(text)  # as the whole text is split
