"""Post-processing: Bézier curves, jaw shift, ceilings, peak confinement, overlays, closures."""

import numpy as np
import pytest
from scipy.signal import find_peaks

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.targets.tables import phone_targets
from vispeech.motion.arkit import LIP_CLOSED, lip_aperture
from vispeech.motion.track import Track
from vispeech.postprocess import PostprocessConfig, SoftCeiling, postprocess
from vispeech.motion.easing import bezier_ease
from vispeech.postprocess.overlays import consonant_overlays
from vispeech.postprocess.shaping import confine_peaks, shift_range


def thesis_curve(a, c1, c2, t):
    """The thesis's parametric Bézier: (x(t), y(t)) with control points (c1·a, 0), (c2·a, 1)."""
    x = 3 * c1 * a * (1 - t) ** 2 * t + 3 * c2 * a * (1 - t) * t**2 + a * t**3
    return x, 3 * (1 - t) * t**2 + t**3


@pytest.mark.parametrize("c1, c2", [(0.5, 0.5), (0.6, 0.75), (0.0, 1.0)])
def test_bezier_matches_the_parametric_curve(c1, c2):
    t = np.linspace(0, 1, 401)
    x, y = thesis_curve(7.5, c1, c2, t)
    np.testing.assert_allclose(bezier_ease(x, 7.5, c1, c2), y, atol=1e-9)


def test_bezier_endpoints_monotonicity_and_symmetry():
    x = np.linspace(-2, 12, 2001)
    y = bezier_ease(x, 10.0)
    assert y[x <= 0].max() == 0.0 and y[x >= 10].min() == 1.0
    assert (np.diff(y) >= 0).all()
    assert bezier_ease(5.0, 10.0) == pytest.approx(0.5)
    np.testing.assert_allclose(bezier_ease(3.0, 10.0) + bezier_ease(7.0, 10.0), 1.0)  # ease in/out symmetry
    np.testing.assert_allclose(bezier_ease([1.0, 2.0], [2.0, 4.0]), [0.5, 0.5])  # broadcasting lengths
    assert bezier_ease([-0.1, 0.0], 0.0).tolist() == [0.0, 1.0]
    with pytest.raises(VispeechError):
        bezier_ease(1.0, 2.0, 0.8, 0.2)


def test_jaw_shift_is_the_thesis_formula():
    w = np.array([0.1, 0.3, 0.5, 0.2])
    expected = w - (0.5 - w) / (0.5 - 0.1) * 0.07  # w_t - (w_max - w_t)/(w_max - w_min) * a
    np.testing.assert_allclose(shift_range(w, 0.07), expected)
    np.testing.assert_allclose(shift_range(w, 0.07)[[0, 2]], [0.03, 0.5])
    np.testing.assert_array_equal(shift_range(np.full(4, 0.3), 0.07), np.full(4, 0.3))


def test_soft_ceiling_is_the_thesis_formula():
    ceiling = SoftCeiling.relative(a=0.2, b=0.8, reference_max=0.9)  # thesis jawOpen with w*_max = 0.9
    x_max, x_thr = 0.2 * 0.9, 0.8 * 0.2 * 0.9
    w = np.array([0.05, x_thr, 0.5, 0.9])
    expected = np.where(w > x_thr, x_thr + (x_max - x_thr) / (0.9 - x_thr) * (w - x_thr), w)
    np.testing.assert_allclose(ceiling(w), expected)
    assert ceiling(np.array([0.9]))[0] == pytest.approx(x_max)
    with pytest.raises(VispeechError):
        SoftCeiling(threshold=0.5, maximum=0.4)


def test_confine_peaks_keeps_maxima_on_allowed_frames_and_only_lowers():
    rng = np.random.default_rng(3)
    for _ in range(50):
        curve = rng.random(60)
        allowed = rng.random(60) < 0.3
        out = confine_peaks(curve, allowed)
        assert (out <= curve).all() and np.array_equal(out[allowed], curve[allowed])
        peaks, _ = find_peaks(out)
        assert allowed[peaks].all()


def phones_sv() -> PhoneSequence:
    return PhoneSequence(
        [Phone("sil", 0, 0.2), Phone("m", 0.2, 0.3), Phone("a", 0.3, 0.5), Phone("p", 0.5, 0.52),
         Phone("a", 0.52, 0.7), Phone("v", 0.7, 0.8), Phone("a", 0.8, 0.95), Phone("s", 0.95, 1.05),
         Phone("sil", 1.05, 1.3)],
        "sv",
    )


def open_track(phones: PhoneSequence, fps=30.0, channels=("jawOpen", "mouthLowerDownLeft", "mouthUpperUpLeft")):
    """A wide-open mouth throughout, with a jaw bump inside /s/."""
    n = phones.n_frames(fps)
    values = np.full((n, len(channels)), 0.6)
    values[int(1.0 * fps), 0] = 0.9
    return Track(values, channels, fps)


def test_postprocess_closes_bilabials_even_on_an_open_mouth():
    phones = phones_sv()
    track = open_track(phones)
    out = postprocess(track, phones)
    assert out.values.min() >= 0 and out.values.max() <= 1
    assert set(track.channels) < set(out.channels)  # the overlay channels were added
    aperture = lip_aperture(out)
    assert aperture[7:9].min() <= LIP_CLOSED  # /m/, 0.2-0.3 s
    assert aperture[15] <= LIP_CLOSED  # /p/ is shorter than a frame: its nearest frame (0.51 s)
    contact = (aperture <= LIP_CLOSED) & (out["mouthRollLower"] >= 0.3)
    assert contact[21:24].any()  # /v/, 0.7-0.8 s
    np.testing.assert_array_equal(track.values, open_track(phones).values)  # input untouched


def test_postprocess_jaw_peaks_stay_in_vowels_and_overlays_never_raise_the_jaw():
    phones = phones_sv()
    track = open_track(phones)
    config = PostprocessConfig(jaw_shift=0.0, ceilings={})
    out = postprocess(track, phones, config)
    assert (out["jawOpen"] <= track["jawOpen"] + 1e-12).all()
    peaks, _ = find_peaks(out["jawOpen"], prominence=0.02, height=0.05)
    vowels = [p for p in phones if p.symbol == "a"]
    assert len(peaks) and all(any(v.start - 1 / 30 <= k / 30 <= v.end + 1 / 30 for v in vowels) for k in peaks)
    kept = postprocess(track, phones, PostprocessConfig(jaw_shift=0.0, ceilings={}, jaw_peaks_in_vowels=False))
    assert kept["jawOpen"][30] > out["jawOpen"][30]  # the bump inside /s/ is what confinement removes


def test_postprocess_steps_can_be_switched_off():
    phones = phones_sv()
    track = open_track(phones)
    off = PostprocessConfig(jaw_shift=0.0, overlays=False, jaw_peaks_in_vowels=False, ceilings={}, close_within_jaw=False,
                            vowel_opening=0.0, tongue=False, rest=False)
    out = postprocess(track, phones, off)
    assert out.channels == track.channels
    np.testing.assert_array_equal(out.values, track.values)
    ceiled = postprocess(track, phones, PostprocessConfig(jaw_shift=0.0, overlays=False, jaw_peaks_in_vowels=False))
    assert ceiled["jawOpen"].max() == pytest.approx(SoftCeiling(0.45, 0.55)(np.array([0.9]))[0])
    with pytest.raises(VispeechError):
        PostprocessConfig(jaw_shift=-1.0)


def test_consonant_overlay_reaches_the_viseme_on_the_anchor_frame_and_fades():
    phones = PhoneSequence([Phone("a", 0, 0.5), Phone("t", 0.5, 0.6), Phone("a", 0.6, 1.2)], "sv")
    track = Track(np.full((phones.n_frames(30), 1), 0.5), ("mouthLowerDownLeft",), 30)
    out = consonant_overlays(track, phones)["mouthLowerDownLeft"]
    target = phone_targets("t", "sv")["mouthLowerDownLeft"]
    assert out[15] == pytest.approx(target) and out[16] == pytest.approx(target)  # onset to anchor (0.5-0.55 s)
    assert out[0] == 0.5 and out[-1] == 0.5
    assert out[10] == 0.5 and 0.5 > out[12] > out[14]  # fade-in starts 1.5 phone lengths (4.5 frames) early
    assert out[16] < out[18] < out[19] == 0.5  # /t/ fades out over 1.0 phone length


def test_upper_lip_overlay_lifts_during_speech_only():
    phones = phones_sv()
    track = Track(np.zeros((phones.n_frames(30), 1)), ("mouthUpperUpLeft",), 30)
    lifted = postprocess(track, phones, PostprocessConfig(upper_lip=0.2, overlays=False))
    up = lifted["mouthUpperUpLeft"]
    assert up[:6].max() == 0.0 and up[33:].max() == 0.0
    assert up[11] == pytest.approx(0.2) and 0 < up[30] < 0.2


def test_short_vowels_between_bilabials_still_open_the_mouth():
    """"my mom": closures on every /m/, yet no mouth kept shut through the vowels."""
    timing = [("M", 0.0, 0.073), ("AY", 0.073, 0.138), ("M", 0.138, 0.213), ("AA", 0.213, 0.315),
              ("M", 0.315, 0.457), ("sil", 0.457, 0.6)]
    phones = PhoneSequence([Phone(s, a, b, stress=1 if s in ("AY", "AA") else 0) for s, a, b in timing], "en")
    fps = 30.0
    n = phones.n_frames(fps)
    channels = ("jawOpen", "mouthClose")
    values = np.zeros((n, 2))
    for p in phones:
        if p.symbol in ("AY", "AA"):
            values[int(np.ceil(p.start * fps)):int(np.ceil(p.end * fps)), 0] = 0.35
    aperture = lip_aperture(postprocess(Track(values, channels, fps), phones))
    for p in phones:
        frames = np.arange(int(np.ceil(p.start * fps - 1e-9)), int(np.ceil(p.end * fps - 1e-9)))
        if p.symbol == "M":
            assert aperture[frames].min() <= LIP_CLOSED
        elif p.symbol in ("AY", "AA"):
            assert aperture[frames].max() >= 0.2, (p.symbol, aperture[frames])


def test_open_vowels_opens_a_one_frame_vowel_between_bilabials_and_keeps_their_closures():
    from vispeech.postprocess.overlays import open_vowels

    # sv "mamma ja": m a(1 frame) m a ... j A: ; closed lips on the short /a/ as a network left them
    timed = [("m", 0.0, 0.1), ("a", 0.1, 0.14), ("m", 0.14, 0.2), ("a", 0.2, 0.3), ("j", 0.3, 0.4),
             ("A:", 0.4, 0.7), ("sil", 0.7, 0.8)]
    phones = PhoneSequence([Phone(s, a, b, 0 if s != "sil" else None) for s, a, b in timed], "sv")
    n, fps = 24, 30.0
    jaw = np.full(n, 0.15)
    close = np.full(n, 0.15)  # shut everywhere ...
    close[14:21] = 0.0  # ... but on the long /A:/
    track = Track(np.column_stack([jaw, close]), ("jawOpen", "mouthClose"), fps)
    opened = open_vowels(track, phones, share=0.8)
    aperture = lip_aperture(opened)
    reference = np.percentile(lip_aperture(track)[[4, 8, 16]], 95)  # the vowels' anchor frames
    assert aperture[4] == pytest.approx(0.8 * reference, abs=1e-9)  # the one-frame /a/ (frame 4)
    assert aperture[8] >= 0.8 * reference - 1e-9  # the second /a/
    assert aperture[[1, 2, 5]].max() <= LIP_CLOSED  # the /m/ frames keep their closure
    np.testing.assert_array_equal(opened.values[:, 0], track.values[:, 0])  # mouthClose gave way, not the jaw
    assert open_vowels(track, phones, share=0.0) is track


@pytest.mark.parametrize("model", ["grid-tdnn", "baseline", "cohen-massaro", "ohman", "grid-ohman",
                                   "grid-cohen-massaro"])
def test_vowels_between_bilabials_open_to_half_of_an_open_a(model):
    """Issue 10: every vowel between bilabials opens to at least half of the same model's /a/ in "Ja."."""
    from vispeech.evaluation.closures import is_bilabial, phone_frames
    from vispeech.phonetics.inventory import is_vowel
    from vispeech.pipeline import speak

    for lang, ja, text in (("sv", "Ja.", "Mamma plockar blåbär."), ("en", "Yeah.", "My mom made a large map of the farm.")):
        reference = lip_aperture(speak(ja, lang, model=model).track).max()
        said = speak(text, lang, model=model)
        aperture = lip_aperture(said.track)
        spoken = [p for p in said.phones if not p.is_silence]
        checked = 0
        for before, vowel, after in zip(spoken, spoken[1:], spoken[2:]):
            if is_vowel(vowel.symbol, lang) and is_bilabial(before.symbol, lang) and is_bilabial(after.symbol, lang):
                frames = phone_frames(vowel.start, vowel.end, said.track.fps, said.track.n_frames, pad=0)
                assert aperture[frames].max() >= 0.5 * reference, (model, text, vowel)
                checked += 1
        assert checked >= 2
