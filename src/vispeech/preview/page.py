"""The self-contained preview page: the audio, the animation and a 2D face in one HTML file."""

from __future__ import annotations

import base64
import html
import json
import os
import re
from functools import cache
from importlib import resources
from pathlib import Path

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file
from vispeech.motion.track import Track

_PLACEHOLDER = re.compile(r"\{\{(TITLE|AUDIO|DATA|FACE2D)\}\}")


def render_preview(
    track: Track,
    phones: PhoneSequence | None,
    audio_wav: bytes | None,
    title: str = "vispeech",
) -> str:
    """The preview page as one self-contained HTML document.

    The page plays ``audio_wav`` (a RIFF/WAVE file's bytes, embedded as a data URI; ``None``
    for a silent page with its own clock) and draws a 2D face driven by ``track``, interpolated
    between frames on the audio clock. ``phones`` (optional) label the current phone. The
    track and phones are embedded as JSON (``Track.to_dict`` / ``PhoneSequence.to_dict``) in a
    ``<script type="application/json" id="vispeech-data">`` element; scripts and styles are
    inline, so the page works offline. ``?t=1.23`` or ``#t=1.23`` in its address seeks to that
    time (seconds) and pauses. Raises :class:`VispeechError` on bad input.
    """
    if not isinstance(track, Track):
        raise VispeechError(f"preview needs a Track, got {type(track).__name__}")
    track.validate()
    if track.n_frames == 0:
        raise VispeechError("cannot preview a track with no frames")
    if phones is not None and not isinstance(phones, PhoneSequence):
        raise VispeechError(f"preview phones must be a PhoneSequence or None, got {type(phones).__name__}")
    data = {"track": track.to_dict(), "phones": None if phones is None else phones.to_dict()}
    parts = {
        "TITLE": html.escape(str(title)),
        "AUDIO": _audio_element(audio_wav),
        "DATA": _script_json(data),
        "FACE2D": _resource("face2d.js"),
    }
    return _PLACEHOLDER.sub(lambda m: parts[m.group(1)], _resource("preview.html"))


def write_preview(
    track: Track,
    phones: PhoneSequence | None,
    audio_wav: bytes | None,
    path: str | os.PathLike,
    title: str = "vispeech",
) -> Path:
    """Write :func:`render_preview`'s page to ``path`` (UTF-8) atomically; return the path."""
    page = render_preview(track, phones, audio_wav, title=title)
    target = Path(path)
    with atomic_output_file(target) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return target


def _audio_element(audio_wav: bytes | None) -> str:
    if audio_wav is None:
        return ""
    if not isinstance(audio_wav, (bytes, bytearray, memoryview)):
        raise VispeechError(f"preview audio must be WAV bytes, got {type(audio_wav).__name__}")
    audio_wav = bytes(audio_wav)
    if len(audio_wav) < 12 or audio_wav[:4] != b"RIFF" or audio_wav[8:12] != b"WAVE":
        raise VispeechError("preview audio is not a RIFF/WAVE file")
    encoded = base64.b64encode(audio_wav).decode("ascii")
    return f'<audio id="audio" preload="auto" src="data:audio/wav;base64,{encoded}"></audio>'


def _script_json(data: dict) -> str:
    """JSON safe inside a ``<script>`` element: ``<``, ``>`` and ``&`` written as ``\\u`` escapes."""
    try:
        text = json.dumps(data, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    except ValueError:
        raise VispeechError("preview phones have non-finite times") from None
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def face2d_source() -> str:
    """The 2D face's browser script (``face2d.js``, global ``VispeechFace2D``), as text."""
    return _resource("face2d.js")


@cache
def _resource(name: str) -> str:
    return resources.files(__package__).joinpath(name).read_text(encoding="utf-8")
