"""The self-contained preview page: nothing fetched, audio and animation embedded, exact round-trips."""

import base64
import io
import json
import re
import wave
from html.parser import HTMLParser
from importlib import resources

import numpy as np
import pytest

from vispeech import Phone, PhoneSequence, Track, VispeechError, Word
from vispeech.preview import render_preview, write_preview

DATA_SCRIPT = re.compile(r'<script type="application/json" id="vispeech-data">(.*?)</script>', re.S)


def make_track() -> Track:
    rng = np.random.default_rng(0)
    channels = ("jawOpen", "mouthClose", "mouthPucker", "mouthFunnel", "mouthRollLower",
                "mouthSmileLeft", "mouthSmileRight", "tongueOut")
    return Track(rng.uniform(0, 1, (45, len(channels))), channels, fps=30.0, start_time=0.1)


def make_phones(word: str = "mamma") -> PhoneSequence:
    return PhoneSequence(
        [Phone("sil", 0.0, 0.3), Phone("m", 0.3, 0.45, 0), Phone("a", 0.45, 0.8, 0, stress=1),
         Phone("m", 0.8, 0.95, 0), Phone("a", 0.95, 1.2, 0), Phone("sil", 1.2, 1.5)],
        "sv", [Word(word, 0.3, 1.2)],
    )


def make_wav(seconds: float = 0.5, rate: int = 16000) -> bytes:
    samples = (8000 * np.sin(2 * np.pi * 220 * np.arange(int(seconds * rate)) / rate)).astype("<i2")
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(samples.tobytes())
    return buf.getvalue()


class _Tags(HTMLParser):
    """Every start tag with its attributes."""

    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


def tags(page: str) -> list[tuple[str, dict]]:
    parser = _Tags()
    parser.feed(page)
    return parser.tags


def embedded_data(page: str) -> dict:
    blocks = DATA_SCRIPT.findall(page)
    assert len(blocks) == 1
    return json.loads(blocks[0])


def test_page_fetches_nothing():
    page = render_preview(make_track(), make_phones(), make_wav())
    assert page.startswith("<!DOCTYPE html>")
    assert re.search(r"\b(https?|wss?|ftp):", page, re.I) is None
    assert "@import" not in page and "url(" not in page
    found = tags(page)
    for tag, attrs in found:
        for name in ("src", "href", "srcset", "poster", "data"):
            if name in attrs:
                assert attrs[name].startswith("data:"), (tag, name, attrs[name][:40])
    assert not [t for t, _ in found if t in {"link", "iframe", "img", "object", "embed", "base"}]
    assert all("src" not in attrs for tag, attrs in found if tag == "script")


def test_audio_is_embedded_exactly():
    wav = make_wav()
    audio = [attrs for tag, attrs in tags(render_preview(make_track(), None, wav)) if tag == "audio"]
    assert len(audio) == 1
    prefix = "data:audio/wav;base64,"
    assert audio[0]["src"].startswith(prefix)
    assert base64.b64decode(audio[0]["src"][len(prefix):], validate=True) == wav


def test_track_and_phones_round_trip():
    track, phones = make_track(), make_phones()
    data = embedded_data(render_preview(track, phones, make_wav()))
    back = Track.from_dict(data["track"])
    assert back.channels == track.channels and back.fps == track.fps and back.start_time == track.start_time
    np.testing.assert_array_equal(back.values, np.round(track.values, 6))
    assert PhoneSequence.from_dict(data["phones"]) == phones


def test_text_that_would_end_a_script_survives():
    phones = make_phones(word="</script><script>alert(1)</script> & <!--")
    page = render_preview(make_track(), phones, None, title="<b>mamma</b> & co")
    assert PhoneSequence.from_dict(embedded_data(page)["phones"]) == phones
    assert page.count("</script>") == sum(tag == "script" for tag, _ in tags(page)) == 3
    assert "<title>&lt;b&gt;mamma&lt;/b&gt; &amp; co</title>" in page
    assert "<script>alert(1)" not in page and "<!--" not in page


def test_page_without_audio_or_phones():
    track = make_track()
    page = render_preview(track, None, None)
    assert "<audio" not in page
    data = embedded_data(page)
    assert data["phones"] is None
    assert Track.from_dict(data["track"]).n_frames == track.n_frames


def test_face_script_is_inline():
    script = resources.files("vispeech.preview").joinpath("face2d.js").read_text(encoding="utf-8")
    assert "</script" not in script.lower() and "{{" not in script
    assert "root.VispeechFace2D" in script
    assert script in render_preview(make_track(), None, None)


@pytest.mark.parametrize(
    "args, message",
    [
        ((make_track(), None, b"ID3 not a wave file"), "RIFF/WAVE"),
        ((make_track(), None, "speech.wav"), "WAV bytes"),
        ((Track.zeros(0, ["jawOpen"], 30.0), None, None), "no frames"),
        ((make_track(), ["m", "a"], None), "PhoneSequence"),
        ((np.zeros((3, 2)), None, None), "Track"),
    ],
)
def test_bad_input_is_refused(args, message):
    with pytest.raises(VispeechError, match=message):
        render_preview(*args)


def test_write_preview_is_atomic(tmp_path):
    path = tmp_path / "out" / "preview.html"
    track, phones, wav = make_track(), make_phones(), make_wav()
    assert write_preview(track, phones, wav, path, title="take 1") == path
    first = path.read_text(encoding="utf-8")
    assert first == render_preview(track, phones, wav, title="take 1")
    with pytest.raises(VispeechError):
        write_preview(track, phones, b"not a wav", path)
    assert path.read_text(encoding="utf-8") == first
    assert [p.name for p in path.parent.iterdir()] == ["preview.html"]
