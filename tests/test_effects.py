"""Voice effects for training (frontends.effects) measured on signals whose answer is known, and
the augmented training copies (models.networks.augmentation): audio, track, phones in step."""

import numpy as np
import pytest

from test_audio_networks import synthetic_utterance

from vispeech import VispeechError
from vispeech.frontends import effects
from vispeech.models.networks.augmentation import augmented_copy

RATE = 16000


def harmonic(f0: float, seconds: float = 1.0, formant: float = 1000.0) -> np.ndarray:
    """A vowel-like tone: harmonics of f0 weighted by a resonance at ``formant`` Hz."""
    t = np.arange(int(seconds * RATE)) / RATE
    x = sum(np.sin(2 * np.pi * f0 * k * t) / (1 + ((f0 * k - formant) / 300) ** 2) for k in range(1, int(7000 / f0)))
    return (0.3 * x / np.max(np.abs(x))).astype(np.float32)


def pitch_of(x: np.ndarray) -> float:
    import librosa

    return float(np.median(librosa.yin(x, fmin=60, fmax=800, sr=RATE)))


def centroid(x: np.ndarray) -> float:
    spectrum = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
    f = np.fft.rfftfreq(len(x), 1 / RATE)
    return float((spectrum * f).sum() / spectrum.sum())


def log_spectrogram(x: np.ndarray) -> np.ndarray:
    from vispeech.frontends.features import log_mel, power_spectrogram

    return log_mel(power_spectrogram(x))


def test_a_voice_shift_moves_pitch_and_formants_independently():
    x = harmonic(120)
    octave = effects.shift_voice(x, RATE, pitch=12.0)
    assert len(octave) == len(x) and pitch_of(octave) == pytest.approx(240, rel=0.03)
    shorter_tract = effects.shift_voice(x, RATE, pitch=0.0, formants=1.2)
    assert pitch_of(shorter_tract) == pytest.approx(120, rel=0.03)
    assert centroid(shorter_tract) / centroid(x) == pytest.approx(1.2, rel=0.1)
    with pytest.raises(VispeechError, match="formant factor"):
        effects.shift_voice(x, RATE, formants=2.0)


def test_time_stretch_keeps_the_pitch():
    x = harmonic(150)
    faster = effects.time_stretch(x, 1.25)
    assert abs(len(faster) - len(x) / 1.25) <= 1
    assert pitch_of(faster) == pytest.approx(150, rel=0.03)


def test_a_room_reverberates_for_its_rt60():
    impulse = np.zeros(RATE, dtype=np.float32)
    impulse[100] = 0.5
    out = effects.reverberate(impulse, RATE, rt60=0.4, wet=1.0, rng=np.random.default_rng(0))
    energy = np.convolve(out.astype(np.float64) ** 2, np.ones(160) / 160, mode="same")
    level = 10 * np.log10(energy[100:] / energy[100:].max() + 1e-12)
    assert level[int(0.1 * RATE)] == pytest.approx(-15, abs=4)  # 60 dB over 0.4 s
    assert level[int(0.3 * RATE)] == pytest.approx(-45, abs=6)


@pytest.mark.parametrize("colour", [0.0, 1.0, 2.0])
def test_noise_comes_at_the_signal_to_noise_ratio_asked(colour):
    x = harmonic(130)
    noisy = effects.add_noise(x, 10.0, np.random.default_rng(1), colour)
    noise = noisy.astype(np.float64) - x
    assert 10 * np.log10(np.mean(x.astype(np.float64) ** 2) / np.mean(noise ** 2)) == pytest.approx(10, abs=0.2)


def test_a_telephone_keeps_the_band_from_300_to_3400_hz():
    x = harmonic(100, formant=2000)
    line = effects.telephone(x, RATE)
    spectrum = np.abs(np.fft.rfft(line.astype(np.float64))) ** 2
    f = np.fft.rfftfreq(len(line), 1 / RATE)
    assert len(line) == len(x)
    assert spectrum[f > 4200].sum() < 1e-4 * spectrum.sum()
    assert spectrum[f < 200].sum() < 1e-2 * spectrum.sum()
    band = (f > 500) & (f < 3000)
    original = np.abs(np.fft.rfft(x.astype(np.float64))) ** 2
    assert np.corrcoef(spectrum[band], original[band])[0, 1] > 0.9


@pytest.mark.parametrize("codec", effects.CODECS)
def test_a_lossy_codec_keeps_the_voice_in_time(codec):
    x = synthetic_utterance(np.random.default_rng(0), 0).audio
    coded = effects.lossy(x, RATE, codec, 0.2)
    assert len(coded) == len(x)
    lags = np.arange(-200, 201)
    core = slice(1000, len(x) - 1000)
    match = [np.dot(x[core], np.roll(coded, -lag)[core]) for lag in lags]
    assert lags[int(np.argmax(match))] == 0
    assert np.corrcoef(x, coded)[0, 1] > 0.9


def test_augmented_copies_are_other_voices_with_their_motion_in_step():
    utterance = synthetic_utterance(np.random.default_rng(0), 3)
    copies = [augmented_copy(utterance, k, seed=0) for k in range(1, 13)]
    again = augmented_copy(utterance, 1, seed=0)
    # seeded: the same effects again (Praat's resynthesis adds a dither of its own)
    # (PSOLA places unvoiced pulses at random): the same draws, so the same timing and motion,
    # and nearly the same spectrogram (r about 0.95), not the same samples
    assert len(again.audio) == len(copies[0].audio) and again.phones == copies[0].phones
    np.testing.assert_array_equal(again.track.values, copies[0].track.values)
    assert np.corrcoef(log_spectrogram(again.audio).ravel(), log_spectrogram(copies[0].audio).ravel())[0, 1] > 0.9
    assert len({c.id for c in copies}) == 12 and copies[0].id == "u3~1"
    stretched = 0
    for copy in copies:
        duration = len(copy.audio) / copy.sample_rate
        speed = utterance.phones.duration / copy.phones.duration
        assert duration == pytest.approx(len(utterance.audio) / RATE / speed, abs=0.01)
        assert copy.track.n_frames == int(np.ceil(utterance.track.n_frames / speed))
        if abs(speed - 1) > 1e-9:
            stretched += 1
            # the jaw's peak moves with the speech: at the same share of the utterance
            peak, copy_peak = np.argmax(utterance.track["jawOpen"]), np.argmax(copy.track["jawOpen"])
            assert copy_peak == pytest.approx(peak / speed, abs=1.5)
        else:
            np.testing.assert_array_equal(copy.track.values, utterance.track.values)
        assert copy.landmarks is None and copy.audio_path is None
        assert np.max(np.abs(copy.audio)) <= 0.95 + 1e-6
    assert 2 <= stretched <= 10


def test_an_audio_network_trains_on_its_augmented_copies(monkeypatch):
    from vispeech.models.fitting import Splits
    from vispeech.models.networks import augmentation
    from vispeech.models.networks.audio import AudioCNNNetwork

    rng = np.random.default_rng(0)
    corpus = Splits([synthetic_utterance(rng, i) for i in range(4)], [synthetic_utterance(rng, 50)])
    made = []

    def counted(utterance, index, seed):
        made.append((utterance.id, index, seed))
        return augmented_copy(utterance, index, seed)

    monkeypatch.setattr(augmentation, "augmented_copy", counted)
    seen = []
    original = AudioCNNNetwork._example
    monkeypatch.setattr(AudioCNNNetwork, "_example", lambda self, u: seen.append(u.id) or original(self, u))
    model = AudioCNNNetwork(targets=["jawOpen"], channels=[4, 4, 4], epochs=1, augment=2, seed=7, pitch_copies=0)
    model.fit(corpus, progress=False)
    assert sorted(made) == sorted((f"u{i}", k, 7) for i in range(4) for k in (1, 2))
    assert sorted(seen) == sorted([f"u{i}" for i in range(4)] + [f"u{i}~{k}" for i in range(4) for k in (1, 2)] + ["u50"])
    with pytest.raises(VispeechError, match="augment must be a whole number within 0..8"):
        AudioCNNNetwork(augment=9)
