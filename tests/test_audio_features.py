"""Audio clips and features: checks, resampling, framing, warping, streaming equals offline, and
the same numbers as librosa's (the shipped audio models were trained on librosa's features)."""

import numpy as np
import pytest

from vispeech import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.features import (
    FRAME_RATE, N_FFT, SpectrumStream, audio_features, log_mel, mel_filter_bank, mfcc, power_spectrogram,
    running_normalize, running_normalize_together, speech_level, warp_frequencies,
)


def tone(freq: float, seconds: float, rate: int = 16000) -> np.ndarray:
    t = np.arange(int(seconds * rate)) / rate
    return (0.5 * np.sin(2 * np.pi * freq * t)).astype(np.float32)


def test_clip_checks_and_downmixes():
    stereo = np.column_stack([tone(440, 0.5), -tone(440, 0.5)])
    assert np.allclose(AudioClip.from_array(stereo, 16000).samples, 0.0, atol=1e-6)
    clip = AudioClip.from_array((tone(440, 0.5) * 32767).astype(np.int16), 16000)
    assert clip.samples.dtype == np.float32 and abs(clip.samples).max() == pytest.approx(0.5, abs=1e-3)
    assert AudioClip.from_array(np.full(100, 3.0), 16000).samples.max() == 1.0  # clipped
    pcm = (tone(440, 0.5) * 20000).astype(np.int16)  # stereo 16-bit was averaged to floats, then never scaled
    np.testing.assert_array_equal(AudioClip.from_array(np.column_stack([pcm, pcm]), 16000).samples,
                                  AudioClip.from_array(pcm, 16000).samples)
    for bad, match in [(pcm.astype(np.int32), "floats in \\[-1, 1\\] or 16-bit integers, got int32"),
                       (pcm > 0, "got bool"), (np.column_stack([pcm, pcm]).T.astype(np.float32) / 32768,
                                               "not \\(channels, samples\\)")]:
        with pytest.raises(VispeechError, match=match):
            AudioClip.from_array(bad, 16000)
    for bad, match in [(np.zeros(0), "empty"), (np.array([0.0, np.nan]), "non-finite"),
                       (np.zeros((2, 2, 2)), "1-D")]:
        with pytest.raises(VispeechError, match=match):
            AudioClip.from_array(bad, 16000)
    with pytest.raises(VispeechError, match="sample rate"):
        AudioClip.from_array(np.zeros(10), 100)
    with pytest.raises(VispeechError, match="limit"):
        AudioClip.from_array(np.zeros(601 * 4000, dtype=np.float32), 4000)


@pytest.mark.parametrize("rate", [8000, 22050, 48000])
def test_resampling_keeps_length_and_pitch(rate):
    clip = AudioClip.from_array(tone(500, 1.0, rate), rate).resampled(16000)
    assert clip.sample_rate == 16000 and len(clip.samples) == 16000
    spectrum = np.abs(np.fft.rfft(clip.samples))
    assert np.argmax(spectrum) == pytest.approx(500, abs=2)  # 1 Hz bins


def test_frames_are_centred_every_10_ms():
    samples = np.zeros(16000, dtype=np.float32)
    samples[8000] = 1.0  # a click at 0.5 s
    power = power_spectrogram(samples)
    assert power.shape == (101, 257) and FRAME_RATE == 100
    assert np.argmax(power.sum(axis=1)) == 50


def test_mel_and_mfcc_see_the_tone_band():
    low, high = log_mel(power_spectrogram(tone(300, 1.0))), log_mel(power_spectrogram(tone(3000, 1.0)))
    assert low.shape == (101, 80)
    assert np.argmax(low[50]) < np.argmax(high[50])
    assert mfcc(low).shape == (101, 13)


@pytest.mark.parametrize("n_mels", [13, 40, 80])
def test_mfcc_is_scipys_orthonormal_dct(n_mels):
    """The NumPy DCT-II (the core has no SciPy) gives scipy.fft.dct's coefficients."""
    from scipy.fft import dct

    frames = np.random.default_rng(n_mels).normal(-8.0, 3.0, (200, n_mels)).astype(np.float32)
    expected = dct(frames * (10.0 / np.log(10.0)), axis=1, type=2, norm="ortho")[:, :13].astype(np.float32)
    np.testing.assert_allclose(mfcc(frames), expected, rtol=1e-6, atol=1e-5)


def test_warping_moves_formants_and_keeps_identity():
    power = power_spectrogram(tone(1000, 0.5))
    assert warp_frequencies(power, 1.0) is power
    peak = lambda p: np.argmax(p[25]) * 8000 / 256  # noqa: E731
    assert peak(warp_frequencies(power, 1.1)) == pytest.approx(1100, abs=40)
    assert peak(warp_frequencies(power, 0.9)) == pytest.approx(900, abs=40)


def test_spectrum_stream_equals_offline():
    rng = np.random.default_rng(1)
    samples = rng.normal(0, 0.1, 32123).astype(np.float32)
    stream, parts, i = SpectrumStream(), [], 0
    while i < len(samples):
        n = int(rng.integers(1, 2000))
        parts.append(stream.push(samples[i:i + n]))
        i += n
    parts.append(stream.finish())
    np.testing.assert_allclose(np.concatenate(parts), power_spectrogram(samples), rtol=1e-5, atol=1e-7)


def test_streams_pushed_together_give_what_each_gives_alone():
    """Several spectrum streams pushed at once (one FFT) and their features normalised at once
    give each what it gets alone, whatever the chunk sizes (none, too, and a stream without a
    running state yet)."""
    rng = np.random.default_rng(4)
    signals = [rng.normal(0, 0.1, n).astype(np.float32) for n in (9000, 4000, 12000)]
    alone, together = [SpectrumStream() for _ in signals], [SpectrumStream() for _ in signals]
    states: list = [None] * 3
    alone_states: list = [None] * 3
    mean, std = np.full(5, 0.5), np.full(5, 2.0)
    positions = [0, 0, 0]
    while any(at < len(x) for at, x in zip(positions, signals)):
        chunks = []
        for k, x in enumerate(signals):
            n = int(rng.integers(0, 700))
            chunks.append(x[positions[k]:positions[k] + n])
            positions[k] += n
        powers = SpectrumStream.push_together(together, chunks)
        features = [power[:, :5] for power in powers]
        normalised, states = running_normalize_together(features, mean, std, 50, states)
        for k, (stream, chunk) in enumerate(zip(alone, chunks)):
            power = stream.push(chunk)
            np.testing.assert_array_equal(powers[k], power)
            expected, alone_states[k] = running_normalize(power[:, :5], mean, std, 50, alone_states[k])
            np.testing.assert_allclose(normalised[k], expected, atol=1e-6)


def test_running_normalisation_continues_and_adapts():
    rng = np.random.default_rng(2)
    features = rng.normal(5.0, 2.0, (400, 3))
    whole, _ = running_normalize(features, np.zeros(3), np.ones(3), 100)
    first, state = running_normalize(features[:150], np.zeros(3), np.ones(3), 100)
    rest, _ = running_normalize(features[150:], np.zeros(3), np.ones(3), 100, state)
    np.testing.assert_allclose(np.concatenate([first, rest]), whole, atol=1e-6)
    assert whole[:20].mean() > 2.0  # the prior rules the first frames
    assert abs(whole[-100:].mean()) < whole[:20].mean() / 4  # then the voice heard so far


def test_normalisation_with_a_memory_takes_the_last_frames_heard():
    """With memory_frames the statistics are the prior's and all frames' while no more than that
    many were heard (exactly the cumulative ones), then the last memory_frames frames' alone, as
    a frame-by-frame loop finds them; they continue across calls and streams side by side, and
    follow a change of level that the cumulative ones lag behind."""
    rng = np.random.default_rng(5)
    mean, std = rng.normal(size=4), rng.uniform(0.5, 2.0, 4)
    features = np.concatenate([rng.normal(3.0, 2.0, (600, 4)), rng.normal(-6.0, 1.0, (600, 4))])
    expected = []
    for t, frame in enumerate(features):
        window = features[max(0, t + 1 - 150) : t + 1]
        prior = 100 if t < 150 else 0
        count = prior + len(window)
        mu = (prior * mean + window.sum(axis=0)) / count
        second = (prior * (std**2 + mean**2) + (window**2).sum(axis=0)) / count
        expected.append((frame - mu) / np.sqrt(second - mu**2))
    whole, _ = running_normalize(features, mean, std, 100, memory_frames=150)
    np.testing.assert_allclose(whole, expected, atol=1e-5)
    cumulative, _ = running_normalize(features, mean, std, 100)
    np.testing.assert_array_equal(whole[:150], cumulative[:150])
    parts, state = [], None
    for start in range(0, len(features), 37):
        part, state = running_normalize(features[start:start + 37], mean, std, 100, state, memory_frames=150)
        parts.append(part)
    np.testing.assert_allclose(np.concatenate(parts), whole, atol=1e-6)
    together, states = running_normalize_together([features[:100], features[:0], features[:700]], mean, std, 100,
                                                  [None, None, None], 150)
    more, _ = running_normalize_together([features[100:200], features[:0], features[700:]], mean, std, 100,
                                         states, 150)
    np.testing.assert_allclose(np.concatenate([together[0], more[0]]), whole[:200], atol=1e-6)
    np.testing.assert_allclose(np.concatenate([together[2], more[2]]), whole, atol=1e-6)
    assert together[1].shape == more[1].shape == (0, 4)
    after = slice(600 + 150, 1200)  # once the window holds only frames after the level fell by 9
    assert abs(whole[after].mean()) < 0.2 and cumulative[after].mean() < -1.0


def test_audio_features_of_a_file(grid_s1):
    clip = AudioClip.read(grid_s1 / "utterances" / "bbaf2n.flac")
    features = audio_features(clip)
    assert features.shape == (len(clip.samples) // 160 + 1, 80) and np.isfinite(features).all()


def librosa_features(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Power spectra, 80 log-mel bands and 13 MFCCs of 16-kHz samples as the models were trained
    on them: with librosa (the ``train`` extra)."""
    import librosa

    padded = np.pad(samples, N_FFT // 2)
    spectrum = librosa.stft(padded, n_fft=N_FFT, hop_length=160, win_length=400, window="hann", center=False)
    power = (np.abs(spectrum) ** 2).T.astype(np.float32)
    bank = librosa.filters.mel(sr=16000, n_fft=N_FFT, n_mels=80, fmin=20.0, fmax=8000.0)
    mel = np.log(np.maximum(power @ bank.T, 1e-6)).astype(np.float32)
    return power, mel, librosa.feature.mfcc(S=mel.T * (10 / np.log(10)), n_mfcc=13).T.astype(np.float32)


def assert_librosas(samples: np.ndarray) -> None:
    power, mel, coefficients = librosa_features(samples)
    ours = power_spectrogram(samples)
    assert ours.shape == power.shape and ours.dtype == np.float32
    np.testing.assert_allclose(ours, power, rtol=1e-6, atol=1e-9 * float(power.max()))
    np.testing.assert_allclose(log_mel(ours), mel, rtol=0, atol=1e-5)
    np.testing.assert_allclose(mfcc(log_mel(ours)), coefficients, rtol=0, atol=1e-4)


def test_features_are_librosas_on_speech(grid_s1):
    for name in ("bbaf2n", "bbaf3s", "lgaz8p"):
        assert_librosas(AudioClip.read(grid_s1 / "utterances" / f"{name}.flac").samples)


@pytest.mark.parametrize("length", [0, 1, 161, 4000, 16001])
def test_features_are_librosas_on_noise_of_any_length(length):
    assert_librosas(np.random.default_rng(length).normal(0, 0.3, length).astype(np.float32))


@pytest.mark.parametrize("n_fft,n_mels,fmin", [(512, 80, 20.0), (512, 40, 20.0), (400, 80, 0.0), (400, 128, 0.0)])
def test_mel_filter_bank_is_librosas(n_fft, n_mels, fmin):
    import librosa

    expected = librosa.filters.mel(sr=16000, n_fft=n_fft, n_mels=n_mels, fmin=fmin)
    bank = mel_filter_bank(16000, n_fft, n_mels, fmin)
    assert bank.dtype == np.float32
    np.testing.assert_allclose(bank, expected, rtol=1e-6, atol=1e-9)


def test_speech_level_is_the_level_of_the_loud_frames():
    """A gain of g dB adds g to the level (the features' floor does not bound it); silence around
    the speech does not move it (while the loud frames are more than 5 % of the clip); a clip of
    no frames has none."""
    rng = np.random.default_rng(3)
    speech = (tone(220, 0.6) * (1 + 0.5 * np.sin(np.linspace(0, 12, 9600))) + 0.01 * rng.normal(size=9600))
    speech = speech.astype(np.float32)
    level = speech_level(power_spectrogram(speech))
    for gain in (-40.0, 6.0):
        gained = speech_level(power_spectrogram(speech * np.float32(10 ** (gain / 20))))
        assert gained == pytest.approx(level + gain, abs=1e-4)
    hiss = (0.001 * rng.normal(size=16000)).astype(np.float32)
    padded = speech_level(power_spectrogram(np.concatenate([hiss, speech, hiss])))
    assert padded == pytest.approx(level, abs=1.0)
    assert speech_level(power_spectrogram(hiss)) < level - 20
    assert np.isnan(speech_level(np.zeros((0, N_FFT // 2 + 1))))
