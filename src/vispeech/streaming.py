"""Streaming animation: frames for phones and for live audio as they arrive (text spoken clause by
clause: :mod:`vispeech.text_stream`).

**Phones.** :func:`open_phone_stream` takes timed phones as a recogniser or a TTS engine
emits them and gives each frame as soon as it may be computed: the model's own
:meth:`~vispeech.models.contract.Estimator.stream` (exact for the time-delay networks, a
re-predicted recent window for the others) gives raw frames once phones cover its
look-ahead, and :class:`PhoneStream` post-processes them on a recent window with the
preset the model recommends.

**Audio.** :class:`LiveAudioStream` takes 16-bit PCM chunks at any sample rate as a
microphone or a voice service delivers them, resamples them to the audio model's rate with
soxr's streaming resampler and gives each frame as soon as the model's
:class:`~vispeech.models.networks.audio_stream.AudioStream` has the audio it looks ahead to,
post-processed frame by frame: the frames equal :func:`~vispeech.pipeline.animate_audio` of
the whole audio (without the closures an audio network's phone head hears offline, and without
the rest in silence, which needs the whole audio's loudness).

**Channels.** Every stream's frames carry :data:`STREAM_CHANNELS`, whatever its model drives
(a channel the model does not drive stays at rest, 0: the rule models' cheeks and nose, the
audio models' tongue, which only phones tell), then any channels of the model's beyond them:
a client keys one list of channels, text, phone and audio streams alike.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, TypeVar, cast

import numpy as np

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends import vad
from vispeech.frontends.audio import check_sample_rate, resampler_delay
from vispeech.limits import check_fps
from vispeech.models.contract import Estimator
from vispeech.motion.arkit import THESIS_CHANNELS, TONGUE_CHANNELS
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import SILENCE, parse_symbol
from vispeech.pipeline import (
    DEFAULT_FPS,
    animate,
)
from vispeech.postprocess import PostprocessConfig, postprocess
from vispeech.postprocess.rest import EASE, HOLD, REST_CHANNELS, SentFrames, rest_weights

if TYPE_CHECKING:
    from vispeech.models.networks.audio import AudioNetwork
    from vispeech.models.streams import ModelStream

MAX_PHONE_SECONDS = 10.0
"""Longest step (seconds) from one phone's end to the next's in a phone stream."""
POSTPROCESS_LOOKAHEAD = 2
"""Frames a phone stream holds back beyond the model's look-ahead for post-processing."""

_FedT = TypeVar("_FedT", "PhoneStream", "LiveAudioStream")
_ChunkT = TypeVar("_ChunkT")

STREAM_CHANNELS: tuple[str, ...] = (
    THESIS_CHANNELS
    + tuple(name[: -len("Left")] + "Right" for name in THESIS_CHANNELS if name.endswith("Left"))
    + TONGUE_CHANNELS
)
"""The channels every stream's frames begin with, in this order: those the shipped networks
learned from the tracked corpus, and the tongue's (:data:`~vispeech.motion.arkit.TONGUE_CHANNELS`)."""


def _with_stream_channels(channels: Sequence[str]) -> tuple[str, ...]:
    """:data:`STREAM_CHANNELS`, then those of ``channels`` that are not among them."""
    return STREAM_CHANNELS + tuple(name for name in channels if name not in STREAM_CHANNELS)


def stream_channels(model: Estimator, language: str, fps: float) -> tuple[str, ...]:
    """The channels a stream of ``model``'s frames carries for phones of ``language`` (a phone
    set: ``sv``, ``en`` or ``ipa``): :data:`STREAM_CHANNELS` and any others its post-processed
    tracks have. Remembered by the model's channels and post-processing preset, so a stream's
    first frames do not wait for a probe animated anew."""
    key = (model.channels, model.postprocessing, language, fps)
    channels = _CHANNELS.get(key)
    if channels is None:
        probe = PhoneSequence([Phone(SILENCE, 0.0, 1.0 / fps)], language)
        channels = _with_stream_channels(animate(probe, model, fps).channels)
        if len(_CHANNELS) >= MAX_REMEMBERED:
            _CHANNELS.clear()
        _CHANNELS[key] = channels
    return channels


MAX_REMEMBERED = 256
"""Channel lists :func:`stream_channels` remembers (a frame rate is a client's choice)."""
_CHANNELS: dict[tuple, tuple[str, ...]] = {}


class PhoneStream:
    """Post-processed frames for timed phones as they arrive: the engine over a model's
    :meth:`~vispeech.models.contract.Estimator.stream`.

    :meth:`push` checks the next phones (known symbols, time order, no step longer than
    :data:`MAX_PHONE_SECONDS`), hands them to the model's stream and returns ``(start_frame,
    frames)``: the post-processed rows over :attr:`channels` at :attr:`fps` that became
    ready, possibly none; :meth:`finish` returns the rest. Post-processing runs on a window of
    the recent raw frames and phones (``context`` seconds back) and holds each frame back
    :data:`POSTPROCESS_LOOKAHEAD` frames more than the model does.
    """

    def __init__(self, model: Estimator, language: str, fps: float = DEFAULT_FPS, context: float = 0.5) -> None:
        self.model = model
        self.language = language
        self._inner = model.stream(language, fps)
        self.fps = self._inner.fps
        self.channels = stream_channels(model, language, self.fps)
        self.lookahead = self._inner.lookahead + POSTPROCESS_LOOKAHEAD
        self._config = PostprocessConfig.from_preset(model.postprocessing)
        self._context = round(context * self.fps)
        self._raw: list[np.ndarray] = []  # model frames from frame _raw_start on
        self._raw_start = 0
        self._phones: list[Phone] = []
        self.end = 0.0
        """Latest phone end so far, seconds."""
        self.emitted = 0
        """Frames given so far."""
        self.closed = False

    def check(self, phones: Iterable[Phone]) -> list[Phone]:
        """Check ``phones`` as :meth:`push` would (raises :class:`VispeechError`), adding nothing."""
        return self._checked(phones)

    def push(self, phones: Iterable[Phone]) -> tuple[int, np.ndarray]:
        """Add phones; the frames that became ready."""
        self.feed(phones)
        return self.collect()

    def feed(self, phones: Iterable[Phone]) -> None:
        """:meth:`push`'s first half: check and add the phones, leaving the model's work to
        :func:`push_together` or :meth:`collect`."""
        new = self._checked(phones)
        if new:
            self._phones += new
            self.end = new[-1].end
        self._inner.feed(new)

    def collect(self) -> tuple[int, np.ndarray]:
        """:meth:`push`'s second half: the frames that became ready since :meth:`feed`."""
        self._raw.extend(self._inner.collect()[1])
        return self._emit(final=False)

    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed, up to the last phone's end."""
        if self.closed:
            raise VispeechError("this phone stream has ended")
        self._raw.extend(self._inner.finish()[1])
        out = self._emit(final=True)
        self.close()
        return out

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self.closed = True
        self._inner.close()

    def _emit(self, final: bool) -> tuple[int, np.ndarray]:
        available = self._raw_start + len(self._raw)
        upto = available if final else available - POSTPROCESS_LOOKAHEAD
        if upto <= self.emitted:
            return self.emitted, np.zeros((0, len(self.channels)))
        first = max(self._raw_start, self.emitted - self._context)
        seconds = first / self.fps
        window = [
            replace(p, start=max(p.start - seconds, 0.0), end=p.end - seconds)
            for p in self._phones
            if p.end > seconds + TIME_TOLERANCE
        ]
        raw = Track(
            np.stack(self._raw[first - self._raw_start : available - self._raw_start]), self._inner.channels, self.fps
        )
        if window:
            raw = postprocess(raw, PhoneSequence(window, self.language), self._config)
        rows = raw.select(self.channels).values[self.emitted - first : upto - first]
        start, self.emitted = self.emitted, upto
        keep = max(0, self.emitted - self._context)
        del self._raw[: max(0, keep - self._raw_start)]
        self._raw_start = max(self._raw_start, keep)
        keep_after = keep / self.fps
        self._phones = [p for p in self._phones if p.end > keep_after] or self._phones[-1:]
        return start, rows

    def _checked(self, phones: Iterable[Phone]) -> list[Phone]:
        """The phones in the inventory's symbols; raises :class:`VispeechError` on bad timing."""
        if self.closed:
            raise VispeechError("this phone stream has ended")
        out = []
        end = self.end
        for p in phones:
            symbol, stress = parse_symbol(p.symbol, self.language)
            if not (math.isfinite(p.start) and math.isfinite(p.end)) or p.end <= p.start:
                raise VispeechError(f"phone {p.symbol!r} at {p.start} s must end after it starts")
            if p.start < end - TIME_TOLERANCE:
                raise VispeechError(
                    f"phone {p.symbol!r} starts at {p.start:.3f} s, before the previous one ends ({end:.3f} s)"
                )
            if p.end - end > MAX_PHONE_SECONDS:
                raise VispeechError(f"phone {p.symbol!r} ends more than {MAX_PHONE_SECONDS:g} s after the one before")
            out.append(Phone(symbol, float(p.start), float(p.end), None, p.stress or stress))
            end = p.end
        return out


def push_together(
    pushes: Sequence[tuple[PhoneStream, Iterable[Phone]]],
) -> list[tuple[int, np.ndarray] | VispeechError]:
    """:meth:`PhoneStream.push` of several streams at once (concurrent sessions of a server): each
    stream's phones are checked and fed, the model work of all of them is done together where the
    model can share it (:meth:`~vispeech.models.streams.ModelStream.advance_together`: one network
    step per frame for every stream of the same network), then each stream's frames are
    post-processed. In the place of a stream whose phones are refused is its :class:`VispeechError`
    (that stream is left as it was); the others go on."""
    return _together([_fed(stream, stream.feed, phones) for stream, phones in pushes])


def push_audio_together(
    pushes: Sequence[tuple[LiveAudioStream, bytes]],
) -> list[tuple[int, np.ndarray] | VispeechError]:
    """:meth:`LiveAudioStream.push` of several streams at once, as :func:`push_together` does for
    phone streams: the voice activity windows of all of them in one call of the detector's
    network, their spectra in one FFT, and for the streams of one audio network its features,
    each convolution layer and the post-processing one call for the new frames of all of them
    (:meth:`LiveAudioStream.collect_together`)."""
    fed = [_fed(stream, stream.feed, pcm) for stream, pcm in pushes]
    frames = iter(LiveAudioStream.collect_together([entry for entry in fed if not isinstance(entry, VispeechError)]))
    return [entry if isinstance(entry, VispeechError) else next(frames) for entry in fed]


def _fed(stream: _FedT, feed: Callable[[_ChunkT], None], chunk: _ChunkT) -> _FedT | VispeechError:
    """``stream`` fed ``chunk`` (by ``feed``), or the :class:`VispeechError` it was refused with."""
    try:
        feed(chunk)
    except VispeechError as exc:
        return exc
    return stream


def _together(fed: Sequence[PhoneStream | VispeechError]) -> list[tuple[int, np.ndarray] | VispeechError]:
    """The model work the fed streams wait on, done together, then each one's frames (or its error)."""
    groups: dict[type[ModelStream], list[ModelStream]] = {}
    for entry in fed:
        if not isinstance(entry, VispeechError):
            groups.setdefault(type(entry._inner), []).append(entry._inner)
    for kind, inner in groups.items():
        kind.advance_together(inner)
    return [entry if isinstance(entry, VispeechError) else entry.collect() for entry in fed]


def open_phone_stream(model: Estimator, language: str, fps: float = DEFAULT_FPS) -> PhoneStream:
    """A :class:`PhoneStream` of ``model`` for phones of ``language`` at ``fps``."""
    return PhoneStream(model, language, fps)


class LiveAudioStream:
    """Frames for live speech audio: 16-bit PCM chunks in, post-processed frames out, the engine
    over an audio model's :meth:`~vispeech.models.contract.Estimator.stream`.

    :meth:`push` takes the next chunk (little-endian mono 16-bit PCM bytes at
    :attr:`sample_rate` Hz) and returns ``(start_frame, frames)``: the rows over :attr:`channels`
    at :attr:`fps` that became ready, possibly none; :meth:`finish` returns the rest, up to the
    audio's end (``ceil(duration · fps)`` frames in all). Audio at another rate than the model's
    is resampled by soxr's streaming resampler (the quality offline resampling uses). A frame
    comes once :attr:`delay` seconds of audio after its time are in. The model's post-processing
    preset must act frame by frame (the ``audio`` preset: clipping and ``mouthClose ≤ jawOpen``),
    so the frames equal :func:`~vispeech.pipeline.animate_audio` of the whole audio, but for the
    closures a model's phone head hears (``closure_threshold``), which only offline animation
    makes (the live ``grid-audio-cnn`` hears no closures), and for the mouth at rest in silence,
    over :attr:`channels`, those of every stream (:data:`STREAM_CHANNELS`: the tongue at rest).

    The mouth rests where Silero VAD (:class:`~vispeech.frontends.vad.VoiceActivity`) hears no
    speech, as offline animation rests it away from the loudness span
    (:mod:`vispeech.postprocess.rest`), between utterances too; a frame's rest is decided from the
    speech heard up to :attr:`delay` after it.
    """

    def __init__(self, model: Estimator, sample_rate: int, fps: float = DEFAULT_FPS) -> None:
        if model.input_kind != "audio":
            raise VispeechError(f"model {model.name} animates phones, not audio: use an audio model")
        check_sample_rate(sample_rate)
        config = PostprocessConfig.from_preset(model.postprocessing)
        config = self._config = replace(config, rest=False)  # the speech's span needs the whole audio
        if config.jaw_shift or config.overlays or config.upper_lip or config.jaw_peaks_in_vowels:
            raise VispeechError(
                f"model {model.name}'s post-processing ({model.postprocessing}) needs the whole "
                "utterance: it cannot animate live audio"
            )
        self.model = model
        # an audio model that streams is an audio network: its stream takes no language, and is an AudioStream
        self._inner = cast("AudioNetwork", model).stream(None, check_fps(fps))
        self.fps = self._inner.fps
        self.channels = _with_stream_channels(self._inner.channels)
        self.sample_rate = sample_rate
        self._resampler = None
        resampling_delay = 0.0
        if sample_rate != self._inner.sample_rate:
            import soxr

            self._resampler = soxr.ResampleStream(
                sample_rate, self._inner.sample_rate, 1, dtype="float32", quality="HQ"
            )
            resampling_delay = resampler_delay(sample_rate, self._inner.sample_rate)
        self.delay = self._inner.delay + resampling_delay
        """Seconds of audio after a frame's time that the stream waits for before giving it."""
        self.lookahead = math.ceil(self.delay * self.fps - 1e-9)
        """:attr:`delay` in whole frames."""
        self.samples = 0
        """Samples received so far, at :attr:`sample_rate`."""
        self.closed = False
        self.activity = vad.VoiceActivity() if self._inner.sample_rate == vad.SAMPLE_RATE else None
        """The stream's voice activity detector (``None`` for a network at another rate: no rest)."""
        self._unheard: list[np.ndarray] = []  # audio fed that the detector has not heard yet
        self.sent = SentFrames(len(self.channels), self.fps)
        self._columns = [self.channels.index(name) for name in self._inner.channels]  # of the model's channels
        self._resting = [j for j, name in enumerate(self.channels) if name in REST_CHANNELS]

    @property
    def duration(self) -> float:
        """Seconds of audio received so far."""
        return self.samples / self.sample_rate

    @property
    def emitted(self) -> int:
        """Frames given so far."""
        return self._inner.emitted

    def cancel(self, frame: int | None = None) -> tuple[int, np.ndarray]:
        """End the stream at once (the listener interrupted), or after it ended: the frames easing
        the face to rest from frame ``frame`` (``None``: the last given), after it (:meth:`SentFrames.ease`)."""
        self.close()
        return self.sent.ease(frame)

    def push(self, pcm: bytes) -> tuple[int, np.ndarray]:
        """Add a chunk of PCM bytes; the frames that became ready."""
        self.feed(pcm)
        return self.collect()

    def feed(self, pcm: bytes) -> None:
        """:meth:`push`'s first half: check and add the chunk, leaving the model's work to
        :func:`push_audio_together` or :meth:`collect`."""
        if self.closed:
            raise VispeechError("this audio stream has ended")
        if len(pcm) % 2:
            raise VispeechError(f"16-bit PCM has 2 bytes a sample: a chunk of {len(pcm)} bytes is cut short")
        samples = np.frombuffer(pcm, dtype="<i2").astype(np.float32) / 32768.0
        self.samples += len(samples)
        if self._resampler is not None:
            samples = self._resampler.resample_chunk(samples)
        if self.activity is not None:
            self._unheard.append(samples)
        self._inner.feed(samples)

    def collect(self) -> tuple[int, np.ndarray]:
        """:meth:`push`'s second half: the frames that became ready since :meth:`feed`."""
        return self.collect_together([self])[0]

    @staticmethod
    def collect_together(streams: Sequence[LiveAudioStream]) -> list[tuple[int, np.ndarray]]:
        """:meth:`collect` of several streams at once: the voice activity windows of all of them
        in one call, the network work together
        (:meth:`~vispeech.models.networks.audio_stream.AudioStream.advance_together`), the new
        frames of the streams of one model post-processed in one call."""
        heard = [(stream.activity, stream._heard()) for stream in streams if stream.activity is not None]
        vad.VoiceActivity.push_together([activity for activity, _ in heard], [audio for _, audio in heard])
        if streams:
            type(streams[0]._inner).advance_together([stream._inner for stream in streams])
        return _postprocessed(streams, [stream._inner.collect() for stream in streams])

    def finish(self) -> tuple[int, np.ndarray]:
        """End the stream; the frames still owed."""
        if self.closed:
            raise VispeechError("this audio stream has ended")
        start = self.emitted
        rows = []
        if self._resampler is not None:
            tail = self._resampler.resample_chunk(np.zeros(0, np.float32), last=True)
            if self.activity is not None:
                self._unheard.append(tail)
            rows.append(self._inner.push(tail)[1])
        if self.activity is not None:
            self.activity.push(self._heard())
        rows.append(self._inner.finish()[1])
        self.close()
        return _postprocessed([self], [(start, np.concatenate(rows))])[0]

    def close(self) -> None:
        """Drop the stream (a client went away); safe to call more than once."""
        self.closed = True
        self._inner.close()

    def _heard(self) -> np.ndarray:
        """The audio fed since the detector last heard it (taken)."""
        audio, self._unheard = np.concatenate([np.zeros(0, np.float32), *self._unheard]), []
        return audio


def _postprocessed(
    streams: Sequence[LiveAudioStream], raw: Sequence[tuple[int, np.ndarray]]
) -> list[tuple[int, np.ndarray]]:
    """Each stream's model frames ``raw[i]`` (start frame, rows) post-processed over its
    :attr:`~LiveAudioStream.channels`, the mouth at rest away from the speech its detector heard,
    and noted as sent: those of one model in one call."""
    out = [(start, np.zeros((0, len(stream.channels)))) for stream, (start, _) in zip(streams, raw)]
    groups: dict[int, list[int]] = {}
    for k, (stream, (_, rows)) in enumerate(zip(streams, raw)):
        if len(rows):
            groups.setdefault(id(stream.model), []).append(k)
    for members in groups.values():
        first = streams[members[0]]
        values = postprocess(
            Track(np.concatenate([raw[k][1] for k in members]), first._inner.channels, first.fps), None, first._config
        ).values
        rows = np.zeros((len(values), len(first.channels)))
        rows[:, first._columns] = values
        bounds = np.cumsum([0] + [len(raw[k][1]) for k in members]).tolist()
        heard = [(k, a, b) for k, a, b in zip(members, bounds, bounds[1:]) if streams[k].activity is not None]
        if heard:
            keep = 1.0 - _rest_together(
                [raw[k][0] / first.fps + np.arange(b - a) / first.fps for k, a, b in heard],
                [cast(vad.VoiceActivity, streams[k].activity).spans for k, _, _ in heard],
            )
            at = np.concatenate([np.arange(a, b) for _, a, b in heard])
            rows[at[:, None], first._resting] *= keep[:, None]
        for k, a, b in zip(members, bounds, bounds[1:]):
            streams[k].sent.add(rows[a:b])
            out[k] = (raw[k][0], rows[a:b])
    return out


def _rest_together(times: Sequence[np.ndarray], spans: Sequence[np.ndarray]) -> np.ndarray:
    """:func:`~vispeech.postprocess.rest.rest_weights` of several streams' frame times (seconds),
    each by its own speech ``spans[i]``, in one call: stream i's times and spans moved ``i`` gaps
    later, a gap outlasting every time and span by more than the hold and ease, so that no
    stream's speech comes near another's frames."""
    ends = [t[-1] for t in times if len(t)] + [s[-1, 1] for s in spans if len(s)]
    gap = max(ends, default=0.0) + 2 * (HOLD + EASE) + 1.0
    shifted = np.concatenate([t + i * gap for i, t in enumerate(times)])
    speech = np.concatenate([s + i * gap for i, s in enumerate(spans)]).reshape(-1, 2)
    return rest_weights(shifted, speech)
