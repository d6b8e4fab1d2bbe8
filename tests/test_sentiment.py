"""How glad or sorry a reply sounds (issue 26, part 3): rules on English and Swedish words, for the
face's expression layer."""

from __future__ import annotations

import pytest

from vispeech.frontends.sentiment import sentiment


@pytest.mark.parametrize(
    ("text", "lang"),
    [
        ("Thank you, that is wonderful news!", "en"),
        ("I'm so happy to hear that. Congratulations!", "en"),
        ("Vad roligt, tack så mycket!", "sv"),
        ("Grattis, det är fantastiskt!", "sv"),
    ],
)
def test_glad_replies_score_high(text, lang):
    assert sentiment(text, lang) > 0.5


@pytest.mark.parametrize(
    ("text", "lang"),
    [
        ("I'm sorry, that is terrible news.", "en"),
        ("Unfortunately I could not find it.", "en"),
        ("Tyvärr är det dåligt väder i dag.", "sv"),
        ("Jag är ledsen, det var hemskt.", "sv"),
    ],
)
def test_sorry_replies_score_low(text, lang):
    assert sentiment(text, lang) < -0.3


def test_plain_negated_and_unknown():
    assert sentiment("The train leaves at nine from platform two.", "en") == 0
    assert sentiment("Tåget går klockan nio.", "sv") == 0
    assert 0 < sentiment("That is not bad.", "en") < sentiment("That is good.", "en")  # negated: mildly good
    assert sentiment("I am not happy.", "en") < 0 and sentiment("Det är inte bra.", "sv") < 0
    assert sentiment("Good. Great. Wonderful. Perfect.", "en") < 1 and sentiment("", "en") == 0
    assert sentiment("Das ist wunderbar.", "de") == 0  # a language the rules do not know: neutral
    assert sentiment("That is wonderful.", "en-gb") == sentiment("That is wonderful.", "en") > 0
    long = "Good. " + "The train leaves at nine from platform two. " * 5
    assert 0 < sentiment(long, "en") < sentiment("Good.", "en")  # one glad word in a long reply counts less
