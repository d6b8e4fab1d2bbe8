"""Non-verbal layers: what a face does besides speaking, as channels of a track.

Each layer is optional, seeded (the same seed gives the same motion) and separable (it sets
only its own channels, none of the speech's), so it is exported like the speech channels:
Live Link Face CSV carries the blinks, the gaze and the head rotation.

- ``blink``: ``eyeBlinkLeft``/``Right``; blinks at a human resting rate (about 17 a minute:
  intervals of 1.5 s plus an exponential of mean 2 s), each closing in 70 ms, held 30 ms,
  opening in 130 ms.
- ``gaze``: ``eyeLook{In,Out,Up,Down}{Left,Right}``; small saccades (within about 7° across,
  5° up and down) every 1 to 3 s, each taking one frame, both eyes together.
- ``head``: ``headYaw``/``headPitch``/``headRoll`` in degrees (as tracked head pose is in a
  corpus, :class:`vispeech.Utterance`); a slow sway (within about 2°,
  eased value noise) and, with phones, a nod on every primary-stressed vowel (the head dips
  1.7° over 300 ms from the vowel's onset).
- ``brows``: ``browInnerUp`` and ``browOuterUp{Left,Right}``; with phones, the brows rise
  (0.3) over 500 ms on the first primary-stressed vowel of every sentence (its emphasis).
- ``breath``: ``breath``, how full the lungs are: 0 at the resting level (the end of a quiet
  exhalation), 1 after a deep breath before a long phrase. At rest a smooth rhythm of 12 to 15
  breaths a minute (each cycle within ±15 % of that), inhaling over 40 % of the cycle and
  exhaling over 60 %, up to 0.35 (the tidal volume). In speech (with phones), a quick
  inhalation of 0.3 to 0.5 s ends at the first phone and at every phone that follows a pause
  of 0.4 s or more, as deep as the coming stretch of speech is long (0.5 plus 0.1 a second, at
  most 1); over the stretch the lungs empty at a steady rate (a straight line) back to 0, and
  the resting rhythm starts again where the speech stops. ``breath`` is vispeech's own channel:
  JSON carries it, Live Link Face CSV (ARKit shapes and head and eye rotations only) does not.
- ``expression``: ``mouthSmile``, ``cheekSquint``, ``mouthFrown``, ``browInnerUp`` and
  ``browDown`` (left and right), gently, by the ``mood`` of what is said (-1 sorry to 1 glad:
  :func:`vispeech.frontends.sentiment.sentiment` of the text): at mood 1 a smile of 0.3 with
  the cheeks raised 0.15 and the brows lifted 0.08; at -1 a frown of 0.2, the inner brows
  raised 0.3 and lowered 0.1 (concern). It eases in over 0.6 s from 0.3 s before the first
  phone (from the start without phones), holds while speaking with a slow drift (±15 %, the
  two sides apart by up to 5 %), and eases out over 1 s after the last phone; each utterance's
  strength is drawn within ±15 %. Its channels are *added* to the track's (the speech's smile
  at /i/ stays, the expression smiles on top; the sum clipped to 1), where every other layer
  replaces its own channels.

:func:`with_life` adds layers to a whole track; :class:`LifePlan` to a stream's frames piece by
piece (a text stream's clauses), drawn over the whole timeline so far.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from vispeech.alignment.phones import Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.motion.easing import smoothstep
from vispeech.motion.rigging.calibration import Calibration
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import is_vowel

LAYERS = ("blink", "gaze", "head", "brows", "breath", "expression")
"""The non-verbal layers, in the order their channels come."""

CHANNELS: dict[str, tuple[str, ...]] = {
    "blink": ("eyeBlinkLeft", "eyeBlinkRight"),
    "gaze": (
        "eyeLookInLeft",
        "eyeLookOutLeft",
        "eyeLookUpLeft",
        "eyeLookDownLeft",
        "eyeLookInRight",
        "eyeLookOutRight",
        "eyeLookUpRight",
        "eyeLookDownRight",
    ),
    "head": ("headYaw", "headPitch", "headRoll"),
    "brows": ("browInnerUp", "browOuterUpLeft", "browOuterUpRight"),
    "breath": ("breath",),
    "expression": (
        "mouthSmileLeft",
        "mouthSmileRight",
        "cheekSquintLeft",
        "cheekSquintRight",
        "mouthFrownLeft",
        "mouthFrownRight",
        "browInnerUp",
        "browDownLeft",
        "browDownRight",
    ),
}
"""The channels each layer sets."""

BLINK_CLOSE, BLINK_HOLD, BLINK_OPEN = 0.07, 0.03, 0.13
BLINK_GAP, BLINK_MEAN_EXTRA = 1.5, 2.0
GAZE_RANGE = (0.25, 0.2)  # ARKit eyeLook weights of the widest saccade: across, up/down
SWAY = (2.0, 1.25, 0.8)  # degrees: yaw, pitch, roll
NOD, NOD_SECONDS = 1.7, 0.3
BROWS, BROWS_SECONDS = 0.3, 0.5
REST_RATE = (12.0, 15.0)  # breaths a minute at rest
REST_JITTER = 0.15  # each resting cycle within this share of the rate's period
REST_INHALE = 0.4  # share of a resting cycle spent inhaling
REST_DEPTH = 0.35  # lungs' fill at the top of a resting breath
SPEECH_INHALE = (0.3, 0.5)  # seconds of the quick inhalation before speech
SPEECH_PAUSE = 0.4  # seconds of silence after which speech resumes with a new breath
SPEECH_DEPTH, SPEECH_DEPTH_PER_S = 0.5, 0.1  # fill after that inhalation: this plus so much per second of speech
GLAD = (0.3, 0.3, 0.15, 0.15, 0.0, 0.0, 0.08, 0.0, 0.0)  # the expression's channels at mood 1
SORRY = (0.0, 0.0, 0.0, 0.0, 0.2, 0.2, 0.3, 0.1, 0.1)  # and at mood -1
EXPRESSION_IN, EXPRESSION_LEAD, EXPRESSION_OUT = 0.6, 0.3, 1.0  # seconds
ADDED = ("expression",)
"""The layers whose channels are added to the track's rather than put in their place."""
REPLAN_EASE = 0.2
"""Seconds over which a :class:`LifePlan` eases a later piece's change to what was drawn before."""


def check_layers(layers: str | Iterable[str]) -> tuple[str, ...]:
    """Layer names from a comma-separated string or a list (``all`` for every layer); an unknown one
    is a :class:`VispeechError`."""
    names = [n.strip() for n in (layers.split(",") if isinstance(layers, str) else layers) if n.strip()]
    if names == ["all"]:
        return LAYERS
    unknown = [n for n in names if n not in LAYERS]
    if unknown:
        raise VispeechError(f"unknown non-verbal layer {unknown[0]!r} (use {', '.join(LAYERS)} or all)")
    return tuple(n for n in LAYERS if n in names)


def nonverbal(
    n_frames: int,
    fps: float,
    phones: PhoneSequence | None = None,
    *,
    layers: Iterable[str] = LAYERS,
    seed: int = 0,
    start_time: float = 0.0,
    mood: float = 0.0,
) -> Track:
    """The channels of ``layers`` over ``n_frames`` frames at ``fps`` (see the module docstring; a
    channel two layers set, ``browInnerUp`` of the brows and the expression, is their sum).

    ``phones`` time the nods, the brows, the breaths taken for speech and the expression
    (without them there are no nods or brows, the breathing is the resting rhythm and the
    expression holds from the start); ``mood`` (-1 to 1) is what the expression shows. Each
    layer draws from its own random stream of ``seed`` (0 or more), so a layer's motion does not
    depend on the others.
    """
    if not -1.0 <= mood <= 1.0:
        raise VispeechError(f"the mood of the expression layer must be from -1 to 1, got {mood}")
    chosen = check_layers(layers)
    if seed < 0:
        raise VispeechError(f"the seed of the non-verbal layers must be 0 or more, got {seed}")
    times = start_time + np.arange(n_frames) / fps
    columns: dict[str, np.ndarray] = {}
    for k, layer in enumerate(LAYERS):
        if layer not in chosen:
            continue
        rng = np.random.default_rng([seed, k])
        if layer == "expression":
            values = _expression(times, rng, phones, mood)
        else:
            values = {"blink": _blinks, "gaze": _gaze, "head": _head, "brows": _brows, "breath": _breath}[layer](
                times, rng, phones
            )
        for name, column in zip(CHANNELS[layer], values.reshape(len(times), -1).T):
            columns[name] = np.minimum(columns[name] + column, 1.0) if name in columns else column
    values = np.column_stack(list(columns.values())) if columns else np.zeros((n_frames, 0))
    return Track(values, tuple(columns), fps, start_time)


def with_life(
    track: Track,
    phones: PhoneSequence | None,
    layers: Iterable[str],
    seed: int = 0,
    scale: Calibration | None = None,
    mood: float = 0.0,
) -> Track:
    """``track`` with the channels of the non-verbal ``layers`` added (replacing any it had, but the
    expression's, which are summed with the track's and clipped to 1; ``mood`` is what it shows);
    ``scale`` puts the added channels in an output scale (for a ``track`` already in it)."""
    life = nonverbal(
        track.n_frames, track.fps, phones, layers=layers, seed=seed, start_time=track.start_time, mood=mood
    )
    return joined(track, life if scale is None else scale.apply(life))


def joined(track: Track, life: Track) -> Track:
    """``track`` with ``life``'s channels (of the same frames) added as :func:`with_life` adds them."""
    if not life.channels:
        return track
    added = {c for layer in ADDED for c in CHANNELS[layer]}
    values = life.values.copy()
    for k, channel in enumerate(life.channels):
        if channel in added and channel in track.channels:
            values[:, k] = np.minimum(values[:, k] + track[channel], 1.0)
    keep = [c for c in track.channels if c not in life.channels]
    return Track(
        np.column_stack([track.select(keep).values, values]), (*keep, *life.channels), track.fps, track.start_time
    )


class LifePlan:
    """The non-verbal ``layers`` of a timeline that grows piece by piece (a stream's clauses).

    :meth:`join` adds the layers to the next piece's frames, drawn over the whole timeline so far
    with every phone so far, so that blinks, gaze and sway go on across pieces as over one track.
    Where a later piece changes what was drawn before (a longer stretch of speech deepens its
    breath, the expression holds on instead of easing out), the change eases in over
    :data:`REPLAN_EASE` seconds from what the earlier piece would have shown next.
    """

    def __init__(self, layers: Iterable[str], fps: float, seed: int = 0, scale: Calibration | None = None) -> None:
        self.layers, self.fps, self.seed, self.scale = check_layers(layers), fps, seed, scale
        if seed < 0:
            raise VispeechError(f"the seed of the non-verbal layers must be 0 or more, got {seed}")
        self.channels = tuple(dict.fromkeys(c for layer in self.layers for c in CHANNELS[layer]))
        """The layers' channels, in the order :func:`nonverbal` gives them."""
        self.frames = 0
        """Frames given so far."""
        self._phones: list[Phone] = []
        self._next: np.ndarray | None = None  # the last draw's row for frame ``frames``

    def joined_channels(self, channels: Iterable[str]) -> tuple[str, ...]:
        """The channels of a track over ``channels`` after :meth:`join`."""
        return (*(c for c in channels if c not in self.channels), *self.channels)

    def join(self, track: Track, phones: Iterable[Phone], language: str, mood: float = 0.0) -> Track:
        """``track``, the timeline's next frames (from :attr:`frames` on), with the layers' channels
        joined as :func:`with_life` joins them; ``phones`` are the piece's, on the timeline, and
        ``mood`` that of everything said so far."""
        self._phones += phones
        end = self.frames + track.n_frames
        said = PhoneSequence(self._phones, language) if self._phones else None
        life = nonverbal(end + 1, self.fps, said, layers=self.layers, seed=self.seed, mood=mood)
        if self.scale is not None:
            life = self.scale.apply(life)
        values = life.values[self.frames :].copy()
        if self._next is not None:
            ease = 1.0 - smoothstep(np.arange(len(values)) / max(1.0, REPLAN_EASE * self.fps))
            values += ease[:, None] * (self._next - values[0])
        start, self.frames, self._next = self.frames, end, values[-1]
        return joined(track, Track(values[:-1], life.channels, self.fps, start / self.fps))


def _blinks(times: np.ndarray, rng: np.random.Generator, phones) -> np.ndarray:
    out = np.zeros(len(times))
    if not len(times):
        return np.column_stack([out, out])
    start = times[0] + rng.uniform(0.3, BLINK_GAP)
    while start < times[-1]:
        dt = times - start
        closing = np.clip(dt / BLINK_CLOSE, 0, 1)
        opening = np.clip(1 - (dt - BLINK_CLOSE - BLINK_HOLD) / BLINK_OPEN, 0, 1)
        out = np.maximum(out, np.where(dt < 0, 0, np.minimum(closing, opening)))
        start += BLINK_CLOSE + BLINK_HOLD + BLINK_OPEN + BLINK_GAP + rng.exponential(BLINK_MEAN_EXTRA)
    return np.column_stack([out, out])


def _gaze(times: np.ndarray, rng: np.random.Generator, phones) -> np.ndarray:
    across, vertical = np.zeros(len(times)), np.zeros(len(times))
    t = times[0] if len(times) else 0.0
    while len(times) and t < times[-1]:
        x, y = rng.uniform(-1, 1) * GAZE_RANGE[0], rng.uniform(-1, 1) * GAZE_RANGE[1]
        after = times >= t
        across[after], vertical[after] = x, y
        t += rng.uniform(1.0, 3.0)
    left_out, left_in = np.maximum(across, 0), np.maximum(-across, 0)  # + looks to the speaker's left
    up, down = np.maximum(vertical, 0), np.maximum(-vertical, 0)
    return np.column_stack([left_in, left_out, up, down, left_out, left_in, up, down])


def _head(times: np.ndarray, rng: np.random.Generator, phones) -> np.ndarray:
    sway = np.column_stack(
        [amplitude * (0.8 * _noise(times, rng, 2.6) + 0.2 * _noise(times, rng, 0.9)) for amplitude in SWAY]
    )
    for onset in _stressed_onsets(phones):
        dt = times - onset
        inside = (dt >= 0) & (dt <= NOD_SECONDS)
        sway[inside, 1] += NOD * np.sin(np.pi * dt[inside] / NOD_SECONDS)  # pitch down and back
    return sway


def _brows(times: np.ndarray, rng: np.random.Generator, phones) -> np.ndarray:
    raise_ = np.zeros(len(times))
    for onset in _stressed_onsets(phones, first_of_sentence=True):
        dt = times - onset + 0.1
        inside = (dt >= 0) & (dt <= BROWS_SECONDS)
        raise_[inside] = np.maximum(raise_[inside], BROWS * np.sin(np.pi * dt[inside] / BROWS_SECONDS))
    return np.column_stack([raise_, raise_, raise_])


def _breath(times: np.ndarray, rng: np.random.Generator, phones) -> np.ndarray:
    out = np.zeros(len(times))
    if not len(times):
        return out
    period = 60.0 / rng.uniform(*REST_RATE)

    def resting(origin: float, until: float):
        """The resting rhythm from ``origin`` (a cycle starting at 0 there), as a function of time."""
        n = int((until - origin) / (period * (1 - REST_JITTER))) + 2
        ends = origin + np.cumsum(period * rng.uniform(1 - REST_JITTER, 1 + REST_JITTER, n))
        starts = np.concatenate([[origin], ends[:-1]])

        def at(t: np.ndarray) -> np.ndarray:
            k = np.clip(np.searchsorted(ends, t, side="right"), 0, n - 1)
            u = np.clip((t - starts[k]) / (ends[k] - starts[k]), 0, 1)
            inhaling = u < REST_INHALE
            w = np.where(inhaling, u / REST_INHALE, (u - REST_INHALE) / (1 - REST_INHALE))
            return REST_DEPTH * np.where(inhaling, 0.5 - 0.5 * np.cos(np.pi * w), 0.5 + 0.5 * np.cos(np.pi * w))

        return at

    end = times[-1]
    rest = resting(times[0] - rng.uniform(0, period), end)  # a random phase at the start
    since = -np.inf  # where the current resting stretch began
    for onset, finish in _speech_stretches(phones):
        begin = max(onset - rng.uniform(*SPEECH_INHALE), since)
        before = (times >= since) & (times < begin)
        out[before] = rest(times[before])
        low = float(rest(np.array([begin]))[0])
        top = min(1.0, SPEECH_DEPTH + SPEECH_DEPTH_PER_S * (finish - onset))
        inhaling = (times >= begin) & (times < onset)
        w = (times[inhaling] - begin) / (onset - begin)
        out[inhaling] = low + (top - low) * (0.5 - 0.5 * np.cos(np.pi * w))
        speaking = (times >= onset) & (times < finish)
        out[speaking] = top * (1 - (times[speaking] - onset) / (finish - onset))
        rest, since = resting(finish, max(end, finish)), finish
    after = times >= since
    out[after] = rest(times[after])
    return out


def _expression(times: np.ndarray, rng: np.random.Generator, phones: PhoneSequence | None, mood: float) -> np.ndarray:
    spoken = [p for p in phones or () if not p.is_silence and p.end > p.start]
    start = spoken[0].start - EXPRESSION_LEAD if spoken else (times[0] if len(times) else 0.0)
    on = smoothstep(times, (start, start + EXPRESSION_IN))
    if spoken:
        on = on * (1 - smoothstep(times, (spoken[-1].end, spoken[-1].end + EXPRESSION_OUT)))
    strength = abs(mood) * rng.uniform(0.85, 1.15) * (1 + 0.15 * _noise(times, rng, 2.5))
    sides = 1 + rng.uniform(-0.05, 0.05) * np.array([1, -1, 1, -1, 1, -1, 0, 1, -1])
    shape = np.array(GLAD if mood >= 0 else SORRY) * sides
    return np.clip((on * strength)[:, None] * shape, 0.0, 1.0)


def _speech_stretches(phones: PhoneSequence | None) -> list[tuple[float, float]]:
    """(start, end) seconds of the stretches of speech: phones with no pause of
    :data:`SPEECH_PAUSE` or more between them."""
    stretches: list[list[float]] = []
    for p in phones or ():
        if p.is_silence or p.end <= p.start:
            continue
        if stretches and p.start - stretches[-1][1] < SPEECH_PAUSE:
            stretches[-1][1] = max(stretches[-1][1], p.end)
        else:
            stretches.append([p.start, p.end])
    return [(a, b) for a, b in stretches]


def _stressed_onsets(phones: PhoneSequence | None, first_of_sentence: bool = False) -> list[float]:
    """Onsets (seconds) of primary-stressed vowels; with ``first_of_sentence`` only the first after
    each long silence (a pause of 0.2 s or more, or the start)."""
    if phones is None:
        return []
    onsets, waiting = [], True
    for p in phones:
        if p.is_silence:
            waiting = waiting or p.end - p.start >= 0.2
            continue
        if p.stress == 1 and is_vowel(p.symbol, phones.language):
            if waiting or not first_of_sentence:
                onsets.append(p.start)
            waiting = False
    return onsets


def _noise(times: np.ndarray, rng: np.random.Generator, period: float) -> np.ndarray:
    """Eased value noise in [-1, 1] with a knot every ``period`` seconds."""
    if not len(times):
        return np.zeros(0)
    x = (times - times[0]) / period
    knots = rng.uniform(-1, 1, int(x[-1]) + 2)
    i = np.floor(x).astype(int)
    s = smoothstep(x - i)
    return knots[i] + s * (knots[i + 1] - knots[i])
