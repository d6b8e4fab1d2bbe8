"""Browser test of live audio: the chat page's Talk button driven by Chromium's fake microphone,
which plays a GRID recording, against a server with the tiny audio model of ``conftest``.

Its own module because it launches Chromium with fake-media flags: a second Playwright
session cannot start while ``test_browser``'s module-scoped page holds one open. Skipped
(failed under ``CI=true``) as ``test_browser`` is, and also without torch.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SHARED, require
from test_browser import _browser_page, _require_browser, _serving

pytestmark = pytest.mark.browser


LIVE_SECONDS = 4.0
"""How long the fake microphone is listened to (its file, 3 s, loops)."""


def test_talk_button_animates_the_microphone_live(tmp_path, tiny_audio_model):
    """Chromium's fake microphone plays a GRID recording; the chat page's Talk button streams it to
    ``/api/listen``, frames come back while it plays, and the head's jawOpen shows them."""
    _require_browser()
    import soundfile

    source = SHARED / "data" / "grid_s1" / "utterances" / "bbaf2n.flac"
    require(source.is_file(), f"GRID speaker 1 ({source})")
    samples, rate = soundfile.read(source, dtype="int16")
    wav = tmp_path / "microphone.wav"
    soundfile.write(wav, samples, rate, subtype="PCM_16")
    flags = ("--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
             f"--use-file-for-fake-audio-capture={wav}")
    with _serving(tmp_path / "cache.sqlite3", audio_model=str(tiny_audio_model)) as url, \
            _browser_page(f"{url}/?idle=0", flags) as page:
        assert page.is_visible("#mic")
        page.click("#mic")
        page.wait_for_function("document.querySelector('#mic').textContent === 'Stop'", timeout=10_000)
        trace = page.evaluate(
            """async ([seconds]) => {
              // at every draw: frames received, the pose's time, the head's jawOpen and the frames' value there
              const v = window.vispeech, performer = v.performer, draws = [];
              const tick = performer.tick;
              performer.tick = function (...args) {
                tick.apply(this, args);
                const anim = this.animation, jaw = anim.channels.indexOf('jawOpen');
                draws.push({frames: anim.length, state: this.state, shown: v.clock(), jaw: v.influences('jawOpen'),
                            expected: anim.length ? anim.sample(v.clock())[jaw] : null});
              };
              try {
                await new Promise((done) => setTimeout(done, seconds * 1000));
              } finally {
                performer.tick = tick;
              }
              const anim = performer.animation, jaw = anim.channels.indexOf('jawOpen');
              return {draws, framesJaw: anim.frames.map((row) => row[jaw])};
            }""",
            [LIVE_SECONDS],
        )
        page.click("#mic")
        page.wait_for_function("document.querySelector('#mic').textContent === 'Talk'", timeout=10_000)
        status = page.text_content("#status")
        received = page.evaluate("window.vispeech.performer.animation.length")
        assert page.errors == []
    assert not status or "behind the audio" in status, status  # no error (a loaded machine may lag)
    assert received >= 30 * (LIVE_SECONDS - 1.0), received  # frames arrive while the audio plays
    draws = trace["draws"]
    assert draws[-1]["frames"] > draws[0]["frames"]
    jaw = np.array(trace["framesJaw"])
    assert jaw.max() - jaw.min() > 0.05, jaw  # the live frames open and close the jaw
    shown = [d for d in draws if d["state"] == "playing" and d["frames"] and d["shown"] >= 0]
    assert len(shown) >= 3, draws[-5:]
    for d in shown:  # the head shows the frames received, at the clock's time
        assert abs(d["jaw"] - min(max(d["expected"], 0.0), 1.0)) < 1e-3, d
    assert len({round(d["jaw"], 3) for d in shown}) >= 2  # and so the jawOpen morph moves
