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
