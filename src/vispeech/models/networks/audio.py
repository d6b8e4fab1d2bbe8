"""Audio networks: speech audio in, face channels out (PhISANet-style, with an optional CTC head).

Two families read :class:`~vispeech.models.networks.audio_encoding.AudioEncoding` frames
(log-mel or MFCC at ``fps`` = 50 by default, normalised per speaker as audio arrives):

- ``audio-cnn``: PhISANet's streaming decoder, three 1-D convolutions (kernels [15, 7, 3],
  ReLU, per-frame layer norm) whose right contexts add up to ``look_ahead`` frames (8 = 160 ms
  at 50 fps), optionally a forward-only GRU of ``recurrent`` units, and a linear output.
  Frame t depends on inputs ``t - behind .. t + look_ahead`` only (and on the GRU's state),
  so :class:`AudioStream` gives exactly the offline frames.
- ``audio-encdec``: an offline encoder-decoder, a centred convolution encoder and a
  bidirectional GRU decoder over the whole utterance. Streamed, it re-decodes a recent window
  and waits ``stream_lookahead`` frames, an approximation of its offline output.

Training (torch) minimises the MSE of standardised targets plus ``velocity_weight`` and
``acceleration_weight`` times the MSE of their first and second differences (PhISANet's
L_vel, L_accel), plus ``ctc_weight`` (λ_CTC) times a CTC loss of a phone head on the last
hidden layer against the utterance's phone sequence (silences left to the blank). With
``closure_threshold`` > 0 prediction also reports the bilabials the head hears
(:meth:`AudioNetwork.predict_with_closures`, :mod:`vispeech.models.networks.phone_head`),
phones of ``closure_length`` seconds on which post-processing shuts the lips. Robustness to
voices the corpus lacks comes from the running normalisation (of the last ``memory_seconds``
heard, when > 0; with ``match_level``, a clip to predict whose level lies outside the training
clips' is gained into their range first, :class:`AudioEncoding`), vocal-tract-length
perturbation (a warp factor drawn from ``1 ± warp`` per utterance and epoch) and
pitch-shifted copies of the training audio (``pitch_copies`` copies, each shifted by up to
``± pitch_shift`` semitones); ``augment`` adds that many copies of each training utterance as
other voices in other rooms, at other rates and over other channels would have said it, for
either kind of features
(:mod:`vispeech.models.networks.augmentation`); ``feature_dropout`` sets each input dimension to
the training mean over a whole utterance with that probability while training. Prediction runs
on NumPy (:mod:`vispeech.models.networks.kernels`).

With ``features="encoder"`` and ``encoder`` the path of a local wav2vec 2.0 / WavLM / HuBERT
folder (:mod:`vispeech.frontends.encoder`, the ``encoder`` extra), the networks read all of
that encoder's hidden states at 50 fps (``fps`` must be 50), standardised globally, through a
learned softmax-weighted sum of the layers (``LayerFusion``, PhISANet's All-Enc) in front of
the convolutions. Each training utterance is encoded once (kept as float16 while fitting:
about 1 MB per second of audio for a base model). ``normalize``, ``prior_seconds``, ``memory_seconds``,
``match_level``, ``warp``, ``pitch_shift`` and ``pitch_copies`` act on spectral features only: the encoder reads the
waveform, and re-encoding pitch-shifted copies would multiply the encoding time and memory for
an encoder already trained on thousands of voices. Prediction encodes the clip (torch) and runs
the rest on NumPy. A stream (:class:`EncoderStream`) re-encodes the audio from
``encoder_context`` seconds (1) before the first frame it has not computed up to the newest
sample every ``encoder_step`` seconds (0.2), and takes a frame's hidden states once
``encoder_ahead`` seconds (0.2) of audio follow it: frames come up to ``encoder_ahead +
encoder_step`` (0.4 s) later than with log-mel, and differ a little from the offline ones (the
encoder attends to a window, not the whole clip), unless the network was trained with
``encoder_streamed``: then training, prediction and the stream all read the states as the
stream computes them, and the stream equals the offline output.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Self

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.encoder import FRAME_RATE as ENCODER_RATE
from vispeech.frontends.features import FRAME_RATE, SAMPLE_RATE, power_spectrogram, warp_frequencies
from vispeech.models.fitting import FitRun, Splits, show_progress, training_split
from vispeech.models.networks.audio_encoding import AudioEncoding
from vispeech.models.networks.audio_stream import AudioStream, EncoderStream, speech_encoder
from vispeech.models.networks.kernels import AudioCNNKernel, EncoderDecoderKernel
from vispeech.models.networks.network import TRAINING_PARAMS, Network
from vispeech.models.networks.phone_head import check_closure_params, heard_bilabials
from vispeech.motion.track import Track
from vispeech.phonetics.inventory import get_inventory, is_silence

AUDIO_PARAMS: dict = {
    **{k: v for k, v in TRAINING_PARAMS.items() if k != "motion_weight"},
    "fps": 50.0,
    "standardize": True,
    "epochs": 60,
    "patience": 8,
    "features": "log-mel",
    "encoder": None,
    "encoder_depth": 0,
    "n_mels": 80,
    "n_mfcc": 13,
    "normalize": "running",
    "prior_seconds": 2.0,
    "memory_seconds": 0.0,
    "match_level": False,
    "warp": 0.1,
    "pitch_shift": 2.0,
    "pitch_copies": 1,
    "augment": 0,
    "encoder_ahead": 0.2,
    "encoder_step": 0.2,
    "encoder_context": 1.0,
    "encoder_streamed": False,
    "ctc_weight": 0.0,
    "closure_threshold": 0.0,
    "closure_length": 0.08,
    "velocity_weight": 0.0,
    "acceleration_weight": 0.0,
    "dropout": 0.1,
    "feature_dropout": 0.0,
    "batch_size": 16,
}
"""Hyper-parameters every audio network has (see the module docstring)."""


@dataclass
class _Example:
    """A training utterance: power spectra of its audio (original first, then pitch-shifted
    copies), its network frame count, its phone labels for CTC (1-based, 0 is the blank) and,
    with ``features="encoder"``, the encoder's hidden states instead of spectra (float16)."""

    powers: list[np.ndarray]
    n_frames: int
    labels: np.ndarray
    hidden: np.ndarray | None = None


class AudioNetwork(Network[AudioClip, AudioEncoding]):
    """Base of the audio networks: audio inputs, augmentation, the loss, prediction and streaming."""

    input_kind = "audio"
    defaults = AUDIO_PARAMS

    # -- inputs ----------------------------------------------------------------------------

    def _check_inputs(self) -> None:
        p = self._params
        self._unfitted_encoding(float(p["fps"]))
        for key in ("warp", "pitch_shift", "ctc_weight", "velocity_weight", "acceleration_weight"):
            if not (isinstance(p[key], int | float) and p[key] >= 0):
                raise VispeechError(f"{key} must be a number >= 0, got {p[key]!r}")
        if p["warp"] >= 0.5 or not 0 <= p["dropout"] < 1 or not 0 <= p["feature_dropout"] < 1:
            raise VispeechError("warp must be below 0.5, dropout and feature_dropout within [0, 1)")
        check_closure_params(p["closure_threshold"], p["closure_length"])
        if not (0 <= p["encoder_ahead"] <= 1 and 0.01 <= p["encoder_step"] <= 1 and 0 <= p["encoder_context"] <= 10):
            raise VispeechError(
                "encoder_ahead must lie in [0, 1] s, encoder_step in [0.01, 1] s and encoder_context in [0, 10] s"
            )
        for key in ("pitch_copies", "augment"):
            if not (isinstance(p[key], int) and 0 <= p[key] <= 8):
                raise VispeechError(f"{key} must be a whole number within 0..8, got {p[key]!r}")
        if not isinstance(p["match_level"], bool):
            raise VispeechError(f"match_level must be true or false, got {p['match_level']!r}")
        if p["match_level"] and p["features"] == "encoder":
            raise VispeechError("match_level needs spectral features (a speech encoder reads the waveform)")

    def _unfitted_encoding(self, fps: float) -> AudioEncoding:
        """The audio encoding the parameters ask for at ``fps``, without training statistics."""
        p = self._params
        if p["features"] == "encoder" and fps != ENCODER_RATE:
            raise VispeechError(
                f"an audio network on a speech encoder runs at its {ENCODER_RATE:g} fps, got fps {fps:g}"
            )
        normalize = "global" if p["features"] == "encoder" else p["normalize"]
        return AudioEncoding(
            p["features"],
            p["n_mels"],
            p["n_mfcc"],
            fps,
            normalize,
            p["prior_seconds"],
            p["memory_seconds"],
            encoder=p["encoder"],
            encoder_depth=p["encoder_depth"],
        )

    def _make_encoding(self, train_set: list, corpus) -> AudioEncoding:
        encoding = self._unfitted_encoding(self.fps_)
        self.phones_ = self._phone_vocabulary(train_set)
        self.phone_language_ = train_set[0].phones.language
        if encoding.kind == "encoder":
            encoder = speech_encoder(encoding)
            encoding = replace(encoding, layers=encoder.layers, width=encoder.width)
            self._hidden = {id(u): self._utterance_hidden(u, encoder) for u in train_set}
            return encoding.with_statistics(encoding.features(hidden) for hidden in self._hidden.values())
        self._powers = {id(u): self._utterance_powers(u) for u in train_set}
        if self._params["match_level"]:
            encoding = encoding.with_level_range(powers[0] for powers in self._powers.values())
        return encoding.with_statistics(encoding.features(powers[0]) for powers in self._powers.values())

    @staticmethod
    def _clip(utterance) -> AudioClip:
        samples, sample_rate = utterance.load_audio()
        return AudioClip.from_array(samples, sample_rate, where=f"audio of {getattr(utterance, 'id', '?')}")

    def _utterance_hidden(self, utterance, encoder) -> np.ndarray:
        """The encoder's hidden states of the utterance's audio, float16 (half the memory while fitting)."""
        return self._hidden_states(self._clip(utterance), encoder).astype(np.float16)

    def _hidden_states(self, clip: AudioClip, encoder) -> np.ndarray:
        """``(layers, clip.n_frames(fps), width)`` hidden states of a clip: of the whole clip, or with
        ``encoder_streamed`` as a live stream computes them (:class:`EncoderStream`)."""
        if not self._params["encoder_streamed"]:
            return encoder.hidden_states(clip)
        samples = clip.resampled(SAMPLE_RATE).samples
        stream = EncoderStream(encoder, ENCODER_RATE, self._params)
        step = round(self._params["encoder_step"] * SAMPLE_RATE)
        parts = [stream.push(samples[i : i + step]) for i in range(0, len(samples), step)]
        parts.append(stream.push(np.zeros(0, dtype=np.float32), final=True))
        return np.concatenate(parts, axis=1)

    def _utterance_powers(self, utterance, copies: bool = True) -> list[np.ndarray]:
        """Power spectra of the utterance's audio and (``copies``) of its pitch-shifted copies (seeded by its id)."""
        import zlib

        import librosa

        samples = self._clip(utterance).resampled(SAMPLE_RATE).samples
        powers = [power_spectrogram(samples)]
        p = self._params
        if copies and p["pitch_shift"] and p["pitch_copies"]:
            rng = np.random.default_rng([p["seed"], zlib.crc32(str(getattr(utterance, "id", "")).encode())])
            for _ in range(p["pitch_copies"]):
                steps = float(rng.uniform(-p["pitch_shift"], p["pitch_shift"]))
                shifted = librosa.effects.pitch_shift(samples, sr=SAMPLE_RATE, n_steps=steps, res_type="soxr_hq")
                powers.append(power_spectrogram(shifted))
        return powers

    def _check_warm(self, train_set: list) -> None:
        """A warm start keeps the features' statistics and the CTC head's phones: the corpus's phones
        must be among them (silence aside)."""
        if self.phones_:
            known = set(self.phones_)
            for utterance in train_set:
                unknown = sorted({p.symbol for p in utterance.phones if p.symbol not in known and not p.is_silence})
                if unknown:
                    raise VispeechError(
                        f"utterance {getattr(utterance, 'id', '?')} has phones this model's CTC head "
                        f"does not know: {', '.join(unknown[:5])} (it was trained on "
                        f"{len(self.phones_)} phones)"
                    )

    def _phone_vocabulary(self, train_set: list) -> tuple[str, ...]:
        """The phone labels of the CTC head: the language's inventory without silence (none without CTC)."""
        if not self._params["ctc_weight"]:
            return ()
        language = train_set[0].phones.language
        return tuple(s for s in get_inventory(language).symbols if not is_silence(s))

    def _encode_example(self, utterance, n_frames: int) -> _Example:
        ids: list[int] = []
        if self.phones_:
            index = {s: i + 1 for i, s in enumerate(self.phones_)}
            ids = [index[p.symbol] for p in utterance.phones if p.symbol in index]
        labels = np.asarray(ids, dtype=np.int64)
        if self.encoding_.kind == "encoder":
            hidden = getattr(self, "_hidden", {}).get(id(utterance))
            if hidden is None:
                hidden = self._utterance_hidden(utterance, speech_encoder(self.encoding_))
            return _Example([], n_frames, labels, hidden)
        powers = getattr(self, "_powers", {}).get(id(utterance)) or self._utterance_powers(utterance, copies=False)
        return _Example(powers, n_frames, labels)

    def _encoding_from_dict(self, data: dict) -> AudioEncoding:
        return AudioEncoding.from_dict(data)

    def _fit(self, corpus, run: FitRun) -> Self:
        """Train on ``corpus`` (utterances with audio, phones and tracks); returns ``self``.
        The run settings are :meth:`Network.fit`'s.

        Learns ``encoding_`` (with the training features' statistics), ``phones_`` (the CTC
        head's labels) and ``phone_language_`` (theirs), ``outputs_``, ``fps_``, ``stats_``,
        ``weights_`` and ``history_``.
        """
        try:
            if self._params["augment"]:
                corpus = self._augmented(corpus, run.progress)
            return super()._fit(corpus, run)
        finally:
            self.__dict__.pop("_powers", None)
            self.__dict__.pop("_hidden", None)

    def _augmented(self, corpus, progress: bool | None) -> Splits:
        """The corpus's splits with ``augment`` copies of every training utterance added
        (:func:`~vispeech.models.networks.augmentation.augmented_copy`); validation as it is."""
        from tqdm.auto import tqdm

        from vispeech.models.networks.augmentation import augmented_copy

        train, validation = training_split(corpus)
        copies = self._params["augment"]
        bar = tqdm(total=len(train) * copies, desc="augmenting", unit="utt", disable=not show_progress(progress))
        added = []
        with bar:
            for utterance in train:
                for index in range(1, copies + 1):
                    added.append(augmented_copy(utterance, index, self._params["seed"]))
                    bar.update(1)
        return Splits(train + added, validation)

    # -- training --------------------------------------------------------------------------

    def _batches(self, examples, rng):
        import torch

        order = np.arange(len(examples)) if rng is None else rng.permutation(len(examples))
        size = self._params["batch_size"]
        warp, drop = self._params["warp"], self._params["feature_dropout"]
        batches = []
        for start in range(0, len(order), size):
            chosen = [examples[i] for i in order[start : start + size]]
            inputs = []
            for example, _ in chosen:
                if example.hidden is not None:
                    inputs.append(self.encoding_.encode(example.hidden, example.n_frames))
                    continue
                power = example.powers[0 if rng is None else int(rng.integers(len(example.powers)))]
                if rng is not None and warp:
                    power = warp_frequencies(power, float(rng.uniform(1 - warp, 1 + warp)))
                inputs.append(self.encoding_.encode(power, example.n_frames))
            if rng is not None and drop:
                inputs = [self._drop_features(x, drop, rng) for x in inputs]
            longest = max(len(x) for x in inputs)
            lengths = np.array([len(x) for x in inputs])
            x = np.stack([np.pad(v, ((0, longest - len(v)), (0, 0))) for v in inputs])
            y = np.stack([np.pad(t, ((0, longest - len(t)), (0, 0))) for _, t in chosen])
            labels = [example.labels for example, _ in chosen]
            batches.append(
                (
                    torch.from_numpy(x),
                    torch.from_numpy(y),
                    torch.from_numpy(lengths),
                    torch.from_numpy(np.concatenate(labels)) if labels else None,
                    torch.tensor([len(v) for v in labels]),
                )
            )
        return batches

    def _drop_features(self, inputs: np.ndarray, rate: float, rng: np.random.Generator) -> np.ndarray:
        """``inputs`` (frames × size, normalised) with each feature dimension set to the training
        mean (0) over the whole utterance with probability ``rate``: every stacked frame loses
        the same dimensions, so the network cannot lean on a few of them (a voice's colour)."""
        keep = (rng.random(self.encoding_.dims) >= rate).astype(inputs.dtype)
        return inputs * np.tile(keep, self.encoding_.stack)

    def _data_loss(self, module, batch):
        import torch

        x, y, lengths, labels, label_lengths = batch
        pred, logits = module(x, lengths)
        mask = (torch.arange(x.shape[1])[None, :] < lengths[:, None]).unsqueeze(-1).to(pred.dtype)
        per_value = mask.sum() * pred.shape[-1]
        loss = (((pred - y) ** 2) * mask).sum() / per_value
        p = self._params
        for weight, order in ((p["velocity_weight"], 1), (p["acceleration_weight"], 2)):
            if weight and x.shape[1] > order:
                both = mask[:, order:] * mask[:, :-order]
                diff = (pred.diff(n=order, dim=1) - y.diff(n=order, dim=1)) ** 2
                loss = loss + weight * (diff * both).sum() / (both.sum() * pred.shape[-1]).clamp(min=1)
        if p["ctc_weight"] and logits is not None:
            log_probs = torch.log_softmax(logits, dim=-1).transpose(0, 1)
            ctc = torch.nn.functional.ctc_loss(
                log_probs, labels, lengths, label_lengths, blank=0, reduction="mean", zero_infinity=True
            )
            loss = loss + p["ctc_weight"] * ctc
        return loss, float(lengths.sum())

    # -- prediction ------------------------------------------------------------------------

    @property
    def lookahead(self) -> int:
        """Network frames after frame t whose inputs frame t needs (beside the feature framing)."""
        return self.kernel_ahead

    @property
    def kernel_ahead(self) -> int:
        raise NotImplementedError

    @property
    def context(self) -> int:
        """Network frames before the first frame not yet computed that a stream keeps inputs for."""
        raise NotImplementedError

    @property
    def delay(self) -> float:
        """Seconds of audio after a frame's time that a stream needs before giving it: the
        look-ahead, the stacked feature frames and half the analysis window (with encoder
        features: the look-ahead, ``encoder_ahead`` and at most ``encoder_step``)."""
        fps = getattr(self, "fps_", self._params["fps"])
        p = self._params
        if p["features"] == "encoder":
            return self.lookahead / fps + p["encoder_ahead"] + p["encoder_step"]
        stack = round(FRAME_RATE / fps)
        return self.lookahead / fps + (stack - 1) / FRAME_RATE + 256 / SAMPLE_RATE

    def predict(self, clip: AudioClip, fps: float) -> Track:
        """A track of ``clip.n_frames(fps)`` frames for the audio: predicted at the model's rate, resampled."""
        return self.predict_with_closures(clip, fps)[0]

    def predict_with_closures(self, clip: AudioClip, fps: float) -> tuple[Track, PhoneSequence | None]:
        """:meth:`predict`'s track and the bilabials the CTC head hears in the clip
        (:func:`~vispeech.models.networks.phone_head.heard_bilabials`, possibly none), or
        ``None`` when the network has no head or ``closure_threshold`` is 0."""
        track, posteriors = self.predict_with_posteriors(clip, fps)
        p = self._params
        if posteriors is None or not p["closure_threshold"] or self.phone_language_ is None:
            return track, None
        return track, heard_bilabials(
            posteriors, self.phones_, self.phone_language_, self.fps_, p["closure_threshold"], p["closure_length"]
        )

    def predict_with_posteriors(self, clip: AudioClip, fps: float) -> tuple[Track, np.ndarray | None]:
        """:meth:`predict`'s track and the CTC head's phone posteriors: ``(clip.n_frames(fps_),
        len(phones_) + 1)`` at the network's own rate :attr:`fps_`, column 0 the blank
        (``None`` without a head)."""
        kernel = self.kernel
        self.check_inputs(clip, fps)
        n_model = clip.n_frames(self.fps_)
        if self.encoding_.kind == "encoder":
            source = self._hidden_states(clip, speech_encoder(self.encoding_))
        else:
            source = self.encoding_.matched(power_spectrogram(clip.resampled(SAMPLE_RATE).samples))
        outputs, posteriors = kernel.forward_with_phones(self.encoding_.encode(source, n_model))
        track = Track(self._denormalise(outputs), self.channels, self.fps_)
        n = clip.n_frames(fps)
        if fps != self.fps_ or track.n_frames != n:
            track = track.resample(fps, n_frames=n)
        return track, posteriors

    def stream(self, language: str | None = None, fps: float = 30.0) -> AudioStream:
        """Frames for audio pushed in chunks (:class:`AudioStream`); ``language`` is ignored
        (audio networks are language-independent)."""
        self.check_fitted()
        return AudioStream(self, fps)

    @property
    def postprocessing(self) -> str:
        return "audio"

    def _learned_state(self):
        learned = super()._learned_state()
        if learned is None:
            return None
        state, arrays = learned
        return {**state, "phones": list(self.phones_), "phone_language": self.phone_language_}, arrays

    def _set_learned_state(self, state: dict, arrays: dict[str, np.ndarray]) -> None:
        self.phones_ = tuple(state["phones"])
        self.phone_language_ = state.get("phone_language")  # absent from folders saved before it
        super()._set_learned_state(state, arrays)


def _right_contexts(kernels: list[int], ahead: int) -> list[int]:
    """Split ``ahead`` frames of look-ahead over the layers, earliest first, each at most half its kernel."""
    right = []
    for k in kernels:
        r = min(ahead, (k - 1) // 2)
        right.append(r)
        ahead -= r
    if ahead:
        raise VispeechError(f"look_ahead exceeds what kernels {kernels} can see ahead ({sum(right)} frames)")
    return right


class AudioCNNNetwork(AudioNetwork):
    """PhISANet's streaming CNN: ``kernels`` (15, 7, 3), ``channels`` per layer, ``look_ahead``
    frames; with ``recurrent`` > 0 a forward-only GRU of that many units over the convolutions
    (context from the past, as far back as it learns to keep, at no cost in look-ahead)."""

    family = "audio-cnn"
    defaults = {**AUDIO_PARAMS, "kernels": [15, 7, 3], "channels": [256, 256, 256], "look_ahead": 8, "recurrent": 0}

    def _check_architecture(self) -> None:
        p = self._params
        if not (len(p["kernels"]) == len(p["channels"]) >= 1 and all(k >= 1 and k % 2 for k in p["kernels"])):
            raise VispeechError("kernels must be odd sizes, one per entry of channels")
        if not (isinstance(p["look_ahead"], int) and p["look_ahead"] >= 0):
            raise VispeechError(f"look_ahead must be a whole number of frames >= 0, got {p['look_ahead']!r}")
        if not (isinstance(p["recurrent"], int) and p["recurrent"] >= 0):
            raise VispeechError(f"recurrent must be a whole number of GRU units >= 0, got {p['recurrent']!r}")
        _right_contexts(p["kernels"], p["look_ahead"])

    def _pads(self) -> list[tuple[int, int]]:
        kernels = self._params["kernels"]
        return [(k - 1 - r, r) for k, r in zip(kernels, _right_contexts(kernels, self._params["look_ahead"]))]

    @property
    def kernel_ahead(self) -> int:
        return self._params["look_ahead"]

    @property
    def context(self) -> int:
        """Network frames before frame t that frame t depends on."""
        return sum(behind for behind, _ in self._pads())

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import AudioCNN

        p = self._params
        right = [r for _, r in self._pads()]
        return AudioCNN(
            n_inputs,
            n_outputs,
            list(p["channels"]),
            list(p["kernels"]),
            right,
            p["dropout"],
            len(self.phones_),
            self.encoding_.layers,
            p["recurrent"],
        )

    def _make_kernel(self) -> AudioCNNKernel:
        return AudioCNNKernel(self.weights_, self._pads(), self.encoding_.layers)


class EncoderDecoderNetwork(AudioNetwork):
    """The offline encoder-decoder: conv ``kernels``/``channels`` encoder, a ``layers``-layer
    bidirectional GRU of ``hidden`` units per direction; streamed by re-decoding ``stream_context``
    frames before and waiting ``stream_lookahead`` frames after each new frame."""

    family = "audio-encdec"
    defaults = {
        **AUDIO_PARAMS,
        "kernels": [5, 5],
        "channels": [256, 256],
        "hidden": 128,
        "layers": 2,
        "stream_lookahead": 15,
        "stream_context": 50,
    }

    def _check_architecture(self) -> None:
        p = self._params
        if not (len(p["kernels"]) == len(p["channels"]) and all(k >= 1 and k % 2 for k in p["kernels"])):
            raise VispeechError("kernels must be odd sizes, one per entry of channels")
        if not (
            isinstance(p["hidden"], int) and p["hidden"] >= 1 and isinstance(p["layers"], int) and p["layers"] >= 1
        ):
            raise VispeechError("hidden and layers must be whole numbers >= 1")

    def _pads(self) -> list[tuple[int, int]]:
        return [((k - 1) // 2, (k - 1) // 2) for k in self._params["kernels"]]

    @property
    def kernel_ahead(self) -> int:
        return self._params["stream_lookahead"]

    @property
    def context(self) -> int:
        """Network frames before the first frame not yet given that a stream re-decodes."""
        return self._params["stream_context"]

    def _build_module(self, n_inputs: int, n_outputs: int):
        from vispeech.models.networks.modules import AudioEncoderDecoder

        p = self._params
        return AudioEncoderDecoder(
            n_inputs,
            n_outputs,
            list(p["channels"]),
            list(p["kernels"]),
            p["hidden"],
            p["layers"],
            p["dropout"],
            len(self.phones_),
            self.encoding_.layers,
        )

    def _make_kernel(self) -> EncoderDecoderKernel:
        return EncoderDecoderKernel(self.weights_, self._pads(), self._params["layers"], self.encoding_.layers)
