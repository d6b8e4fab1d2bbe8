"""Stimuli for perceptual tests: the noise-excited vocoder (Beskow 2004, Shannon et al. 1995)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.signal import butter, sosfiltfilt

from vispeech import VispeechError
from vispeech.cli import main
from vispeech.evaluation.stimuli import band_edges, noise_vocode
from vispeech.frontends.audio import read_audio
from vispeech.pipeline import speak


@pytest.fixture(scope="module")
def speech():
    utterance = speak("My mom made a large map of the farm.", "en")
    return utterance.audio.astype(np.float64), utterance.sample_rate


def _envelope(x, rate, lo, hi):
    band = sosfiltfilt(butter(4, [lo, hi], btype="band", fs=rate, output="sos"), x)
    return sosfiltfilt(butter(2, 20, fs=rate, output="sos"), np.abs(band))


def test_the_vocoder_keeps_each_bands_envelope_and_drops_the_voice(speech):
    x, rate = speech
    y = noise_vocode(x, rate)
    assert y.shape == x.shape and y.dtype == np.float32 and np.abs(y).max() <= 1
    assert np.sqrt(np.mean(y.astype(float) ** 2)) == pytest.approx(np.sqrt(np.mean(x ** 2)), rel=0.05)
    edges = band_edges()
    np.testing.assert_allclose(edges, [100, 368.4, 1357.2, 5000], rtol=1e-3)
    for lo, hi in zip(edges[:-1], edges[1:]):  # the syllables' loudness in every band is kept
        assert np.corrcoef(_envelope(x, rate, lo, hi), _envelope(y, rate, lo, hi))[0, 1] > 0.85, (lo, hi)
    # the voice is gone: in the loudest quarter second, speech's autocorrelation peaks at its pitch
    # period (80-300 Hz); the vocoded noise's does not
    def voicing(z):
        z = sosfiltfilt(butter(4, [100, 1000], btype="band", fs=rate, output="sos"), z)
        window = int(0.25 * rate)
        start = int(np.argmax(np.convolve(z ** 2, np.ones(window), "valid")))
        z = z[start:start + window]
        spectrum = np.abs(np.fft.rfft(z, 2 * len(z))) ** 2
        ac = np.fft.irfft(spectrum)[:len(z)]
        return ac[rate // 300:rate // 80].max() / ac[0]
    assert voicing(x) > 0.5 and voicing(y.astype(float)) < 0.3
    spectrum = np.abs(np.fft.rfft(y)) ** 2
    freqs = np.fft.rfftfreq(len(y), 1 / rate)
    assert spectrum[(freqs < 60) | (freqs > 7000)].sum() < 0.02 * spectrum.sum()  # within the bands
    np.testing.assert_array_equal(noise_vocode(x, rate, seed=3), noise_vocode(x, rate, seed=3))
    assert not np.array_equal(noise_vocode(x, rate, seed=3), y)


def test_bad_vocoder_settings():
    with pytest.raises(VispeechError, match="below half the sample rate"):
        noise_vocode(np.zeros(16000), 8000)  # 5000 Hz is beyond 4 kHz
    with pytest.raises(VispeechError, match="50 ms or more"):
        noise_vocode(np.zeros(100), 16000)
    with pytest.raises(VispeechError, match="lowest band edge must lie above 0 and below its highest, got 5000-100"):
        noise_vocode(np.zeros(16000), 16000, low=5000, high=100)
    with pytest.raises(VispeechError, match="narrower than a semitone"):  # they would filter out everything
        noise_vocode(np.zeros(16000), 16000, bands=32, low=100, high=101)


def test_cli_vocodes_a_file(speech, tmp_path):
    from vispeech.frontends.audio import wav_bytes

    x, rate = speech
    (tmp_path / "in.wav").write_bytes(wav_bytes(x.astype(np.float32), rate))
    result = CliRunner().invoke(main, ["stimuli", "vocode", str(tmp_path / "in.wav"), "-o", str(tmp_path / "out.wav")])
    assert result.exit_code == 0 and "3 bands (edges 100, 368, 1357, 5000 Hz)" in result.output, result.output
    y, out_rate = read_audio(tmp_path / "out.wav")
    assert out_rate == rate and len(y) == len(x)
    bad = CliRunner().invoke(main, ["stimuli", "vocode", str(tmp_path / "missing.wav"), "-o", str(tmp_path / "x.wav")])
    assert bad.exit_code == 2 and bad.output.startswith("error:")
    mp3 = CliRunner().invoke(main, ["stimuli", "vocode", str(tmp_path / "in.wav"), "-o", str(tmp_path / "x.mp3")])
    assert mp3.exit_code == 2 and mp3.output == f"error: {tmp_path / 'x.mp3'}: the degraded speech is written as .wav\n"
    assert not (tmp_path / "x.mp3").exists()


def test_faces_render_side_by_side_with_their_sound(tmp_path):
    """Two animations of one sentence, shuffled: the MP4 has a frame per track frame, two faces
    side by side in the key's order, the sound; the mouth is open at an open vowel and shut at /m/."""
    import json

    import av

    from conftest import require, require_module
    from vispeech.frontends.audio import wav_bytes
    from vispeech.models.registry import load_model
    from vispeech.motion.formats.registry import write_track

    require_module("playwright.sync_api", "Playwright (the test extra)")
    from pathlib import Path

    require(Path("/usr/bin/chromium").is_file(), "Chromium (/usr/bin/chromium)")
    tdnn = speak("Father made a map.", "en")
    shut = speak("Father made a map.", "en", model=load_model("baseline"))  # its frames, for the rest pose
    write_track(tdnn.track, tmp_path / "tdnn.json")
    rest = type(shut.track)(np.zeros_like(shut.track.values), shut.track.channels, shut.track.fps)  # never moves
    write_track(rest, tmp_path / "rest.json")
    (tmp_path / "speech.wav").write_bytes(wav_bytes(tdnn.audio, tdnn.sample_rate))
    out = tmp_path / "clip.mp4"
    result = CliRunner().invoke(main, ["stimuli", "render", str(tmp_path / "tdnn.json"), str(tmp_path / "rest.json"),
                                       "--audio", str(tmp_path / "speech.wav"), "--shuffle", "1", "--face-2d",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    key = json.loads((tmp_path / "clip.json").read_text())
    assert sorted(Path(p).name for p in key["left_to_right"]) == ["rest.json", "tdnn.json"] and key["seed"] == 1
    with av.open(str(out)) as container:
        assert {s.type for s in container.streams} == {"video", "audio"}
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == tdnn.track.n_frames and frames[0].shape[1] == 2 * frames[0].shape[0] * 4 // 5
    speaking = [Path(p).name for p in key["left_to_right"]].index("tdnn.json")
    vowel = next(p for p in tdnn.phones if p.symbol == "AA")
    k = round((vowel.start + vowel.end) / 2 * tdnn.track.fps)
    width = frames[0].shape[1] // 2
    mouth = lambda frame, side: frame[int(0.6 * len(frame)):int(0.72 * len(frame)),  # noqa: E731
                                      side * width + width // 3:side * width + 2 * width // 3].mean()
    assert mouth(frames[k], speaking) < mouth(frames[k], 1 - speaking) - 5  # the open mouth is darker
    assert abs(mouth(frames[0], speaking) - mouth(frames[0], 1 - speaking)) < 3  # both at rest at first


def _require_chromium():
    from pathlib import Path

    from conftest import require, require_module

    require_module("playwright.sync_api", "Playwright (the test extra)")
    require(Path("/usr/bin/chromium").is_file(), "Chromium (/usr/bin/chromium)")


def test_tracks_render_on_the_3d_head_side_by_side(tmp_path):
    """Two 10-frame tracks on the shipped ICT head (the default), swapped by the shuffle: one at
    rest, one opening the jaw. The MP4 has 10 frames of two 320x400 heads and the sound; the opening one is where the key
    says, its mouth region darker than the resting one's by the last frame; the rest of the face
    and the first frame (both at rest) are alike."""
    import json
    from pathlib import Path

    import av

    from vispeech import Track
    from vispeech.frontends.audio import wav_bytes
    from vispeech.motion.arkit import ARKIT_NAMES
    from vispeech.motion.formats.registry import write_track

    _require_chromium()
    rest = Track.zeros(10, ARKIT_NAMES, 25.0)
    opening = Track.zeros(10, [*ARKIT_NAMES, "headYaw"], 25.0)
    opening.values[:, ARKIT_NAMES.index("jawOpen")] = np.linspace(0, 1, 10)
    opening.values[:, ARKIT_NAMES.index("mouthLowerDownLeft")] = np.linspace(0, 0.5, 10)
    opening.values[:, ARKIT_NAMES.index("mouthLowerDownRight")] = np.linspace(0, 0.5, 10)
    write_track(rest, tmp_path / "rest.json")
    write_track(opening, tmp_path / "open.json")
    (tmp_path / "speech.wav").write_bytes(wav_bytes(np.zeros(6400, dtype=np.float32), 16000))
    out = tmp_path / "clip.mp4"
    assert np.random.default_rng(3).permutation(2).tolist() == [1, 0]  # seed 3 swaps the two
    result = CliRunner().invoke(main, ["stimuli", "render", str(tmp_path / "rest.json"), str(tmp_path / "open.json"),
                                       "--audio", str(tmp_path / "speech.wav"), "--shuffle", "3", "-o", str(out)])
    assert result.exit_code == 0, result.output
    key = json.loads((tmp_path / "clip.json").read_text())
    assert [Path(p).name for p in key["left_to_right"]] == ["open.json", "rest.json"]
    assert key["head"].endswith("ict_head.glb")
    with av.open(str(out)) as container:
        assert {s.type for s in container.streams} == {"video", "audio"}
        frames = [f.to_ndarray(format="rgb24").astype(float) for f in container.decode(video=0)]
    assert len(frames) == 10 and frames[0].shape == (400, 640, 3)

    def region(frame, side, top, bottom):  # the middle fifth of a head's width, rows top..bottom of 400
        return frame[top:bottom, side * 320 + 128:side * 320 + 192]

    mouth, brows = (248, 312), (120, 160)
    assert region(frames[-1], 0, *mouth).mean() < region(frames[-1], 1, *mouth).mean() - 10  # open: darker
    assert np.abs(region(frames[-1], 0, *mouth) - region(frames[-1], 1, *mouth)).mean() > 20
    assert np.abs(region(frames[-1], 0, *brows) - region(frames[-1], 1, *brows)).mean() < 3  # the same face
    assert np.abs(region(frames[0], 0, *mouth) - region(frames[0], 1, *mouth)).mean() < 5  # both at rest at first
    assert region(frames[-1], 1, *mouth).std() > 5  # a face is there, not the background


def test_a_head_that_is_not_an_arkit_glb_is_refused(tmp_path):
    """A text file, or a GLB whose morph targets have no ARKit names, as --head: one line `error:`,
    exit 2, no clip and no key; the library raises VispeechError."""
    from test_gltf import tiny_glb

    from vispeech import Track
    from vispeech.evaluation.stimuli import render_faces
    from vispeech.motion.arkit import ARKIT_NAMES
    from vispeech.motion.formats.registry import write_track

    write_track(Track.zeros(3, ARKIT_NAMES, 25.0), tmp_path / "a.json")
    (tmp_path / "notes.glb").write_text("not a head\n")
    tiny_glb(tmp_path / "shapes.glb", ["Key 1", "Smile"])
    for head, extra in [("notes.glb", []), ("shapes.glb", []), ("shapes.glb", ["--head-as-is"]), ("missing.glb", [])]:
        result = CliRunner().invoke(main, ["stimuli", "render", str(tmp_path / "a.json"), *extra,
                                           "--head", str(tmp_path / head), "-o", str(tmp_path / "clip.mp4")])
        assert result.exit_code == 2 and result.output.startswith("error:"), (head, result.output)
        assert result.output.count("\n") == 1, result.output
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "notes.glb", "shapes.glb"]
    for prepare in (True, False):
        with pytest.raises(VispeechError, match="ARKit morph targets"):
            render_faces([Track.zeros(3, ARKIT_NAMES, 25.0)], tmp_path / "clip.mp4", head=tmp_path / "shapes.glb",
                         prepare_head=prepare)
    bad = CliRunner().invoke(main, ["stimuli", "render", str(tmp_path / "a.json"), "--head-as-is",
                                    "-o", str(tmp_path / "clip.mp4")])
    assert bad.exit_code == 2 and "--head-as-is needs --head" in bad.output
    both = CliRunner().invoke(main, ["stimuli", "render", str(tmp_path / "a.json"), "--face-2d",
                                     "--head", str(tmp_path / "shapes.glb"), "-o", str(tmp_path / "clip.mp4")])
    assert both.exit_code == 2 and "not both" in both.output
