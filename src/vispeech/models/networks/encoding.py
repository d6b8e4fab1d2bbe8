"""Per-frame input encodings of a phone sequence for the trainable networks.

Every frame k (at ``k / fps`` seconds) is labelled with the phone covering it
(:meth:`PhoneSequence.frame_indices`, gaps read as ``sil``) and turned into a vector:

- ``kind="phones"``: a one-hot of the model's language inventory (ARPAbet + ``sil``/``sp``
  for English, as Taylor et al. 2017 and the thesis use). Only that language's phones can
  be encoded.
- ``kind="features"``: the language-independent articulatory feature vector of
  :func:`vispeech.phonetics.features.phone_features` (Beskow 2004's 17 features and the
  extras, with stress), so a model trained on English drives Swedish or any language whose
  phones have feature vectors.

Optional extra columns, after those:

- ``linguistic``: Taylor-style binary indicators. Per frame, phone categories (vowel,
  consonant, silence, places, manners, voicing, rounding, vowel height and frontness,
  diphthong) and, on the first frame of a phone, which of 36 transitions it is (previous
  class to this class, over six classes: silence, labial, coronal and dorsal consonants,
  rounded and unrounded vowels). A window over these gives Taylor's "category at frame j"
  and "transition at frames k, k+1" questions; his "phone p spans frames j..k" questions
  are left to the network, which sees identity and phone starts at every window position.
- ``position``: where the frame lies within its phone, 0 at its start to 1 at its end.

Each frame depends only on its own phone and the previous frame's, so frames can be
encoded as phones arrive (:meth:`InputEncoding.encode` with ``start_frame``; see
:class:`~vispeech.models.networks.tdnn.RecurrentStream`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import cache

import numpy as np

from vispeech.alignment.phones import PhoneSequence
from vispeech.errors import VispeechError
from vispeech.phonetics.features import FEATURE_NAMES, phone_rows
from vispeech.phonetics.inventory import SILENCE, get_inventory

INPUT_KINDS = ("phones", "features")
"""The two input kinds: a one-hot of one inventory, or articulatory feature vectors."""

_F = {name: i for i, name in enumerate(FEATURE_NAMES)}

_CATEGORIES: tuple[str, ...] = (
    "vowel",
    "consonant",
    "silence",
    "bilabial",
    "labiodental",
    "dental",
    "alveolar",
    "postalveolar",
    "retroflex",
    "palatal",
    "velar",
    "glottal",
    "nasal",
    "fricative",
    "stop",
    "approximant",
    "lateral",
    "voiced_consonant",
    "voiceless_consonant",
    "rounded",
    "front_vowel",
    "back_vowel",
    "open_vowel",
    "close_vowel",
    "diphthong",
)
_CLASSES: tuple[str, ...] = ("sil", "labial", "coronal", "dorsal", "round", "unround")
LINGUISTIC_NAMES: tuple[str, ...] = tuple(f"is_{c}" for c in _CATEGORIES) + tuple(
    f"{a}>{b}" for a in _CLASSES for b in _CLASSES
)
"""Column names of the ``linguistic`` indicators: categories, then transitions ``a>b``."""


@dataclass(frozen=True)
class InputEncoding:
    """How a :class:`PhoneSequence` becomes network input: ``frames x size`` float32.

    ``language`` is the inventory of a ``"phones"`` encoding (ignored by ``"features"``).
    """

    kind: str = "phones"
    language: str = "en"
    linguistic: bool = False
    position: bool = False

    def __post_init__(self) -> None:
        if self.kind not in INPUT_KINDS:
            raise VispeechError(f"unknown input kind {self.kind!r} (use {' or '.join(INPUT_KINDS)})")
        get_inventory(self.language)

    @property
    def names(self) -> tuple[str, ...]:
        """Name of every input column."""
        if self.kind == "phones":
            base = tuple(f"phone:{s}" for s in get_inventory(self.language).symbols)
        else:
            base = FEATURE_NAMES
        return base + (LINGUISTIC_NAMES if self.linguistic else ()) + (("position",) if self.position else ())

    @property
    def size(self) -> int:
        """Number of input columns per frame."""
        return len(self.names)

    def check(self, phones: PhoneSequence) -> None:
        """Raise :class:`VispeechError` if this encoding cannot take ``phones``' language."""
        if self.kind == "phones" and phones.language != self.language:
            raise VispeechError(
                f"this model's input is a one-hot of {self.language} phones and cannot take "
                f"{phones.language} phones; use a model trained with inputs='features'"
            )

    def encode(
        self, phones: PhoneSequence, fps: float, n_frames: int | None = None, start_frame: int = 0
    ) -> np.ndarray:
        """Input rows for frames ``start_frame .. n_frames - 1`` at ``fps``.

        ``n_frames`` defaults to ``phones.n_frames(fps)``; frames no phone covers read as
        silence. Raises :class:`VispeechError` for a phone the encoding does not know.
        """
        self.check(phones)
        filled = phones.with_gaps_filled()
        n = filled.n_frames(fps) if n_frames is None else n_frames
        every = filled.frame_indices(fps, n)
        index = every[start_frame:]
        segments = filled.phones
        symbols = [p.symbol for p in segments] + [SILENCE]
        table = phone_rows(phones.language)
        row = table.indices(symbols, [p.stress for p in segments] + [0])  # the last: silence
        rows = table.features[row] if self.kind == "features" else self._one_hot(symbols)
        parts = [rows[index]]  # index -1 picks the silence row, last
        if self.linguistic:
            categories, classes = _linguistic(phones.language)
            categories, classes = categories[row], classes[row]
            previous = np.concatenate([every[:1], every[:-1]])[start_frame:]
            changed = np.flatnonzero(index != previous)
            transitions = np.zeros((len(index), len(_CLASSES) ** 2))
            transitions[changed, classes[previous[changed]] * len(_CLASSES) + classes[index[changed]]] = 1.0
            parts += [categories[index], transitions]
        if self.position:
            starts = np.append(filled.starts, 0.0)[index]
            ends = np.append(filled.ends, 1.0)[index]
            times = np.arange(start_frame, n) / fps
            position = np.where(index >= 0, np.clip((times - starts) / (ends - starts), 0.0, 1.0), 0.0)
            parts.append(position[:, None])
        return np.concatenate(parts, axis=1).astype(np.float32)

    def _one_hot(self, symbols: list[str]) -> np.ndarray:
        """One row per symbol: a one-hot of this encoding's inventory."""
        inventory = get_inventory(self.language).symbols
        unknown = [s for s in symbols if s not in inventory]
        if unknown:
            raise VispeechError(f"phone {unknown[0]!r} is not in this model's {self.language} inventory")
        rows = np.zeros((len(symbols), len(inventory)))
        rows[np.arange(len(symbols)), [inventory.index(s) for s in symbols]] = 1.0
        return rows

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> InputEncoding:
        return cls(**{k: data[k] for k in ("kind", "language", "linguistic", "position") if k in data})


@cache
def _linguistic(language: str) -> tuple[np.ndarray, np.ndarray]:
    """Category indicators and broad class of every row of :func:`~vispeech.phonetics.features.phone_rows`."""
    features = phone_rows(language).features
    return _categories(features), _classes(features)


def _categories(features: np.ndarray) -> np.ndarray:
    """Binary category indicators (phones x len(_CATEGORIES)) from feature vectors."""

    def f(name: str) -> np.ndarray:
        return features[:, _F[name]]

    vowel = f("vowel") > 0
    silence = f("silence") > 0
    consonant = ~vowel & ~silence
    columns = [vowel, consonant, silence]
    columns += [f(name) > 0 for name in _CATEGORIES[3:17]]
    columns += [
        consonant & (f("voiced") > 0),
        consonant & (f("voiced") == 0),
        f("rounded") > 0,
        vowel & (f("front") >= 1),
        vowel & (f("front") == 0),
        vowel & (f("open") >= 1),
        vowel & (f("open") == 0),
        f("diphthong") > 0,
    ]
    return np.column_stack(columns).astype(np.float32)


def _classes(features: np.ndarray) -> np.ndarray:
    """Broad class index (into _CLASSES) of each phone: for the transition indicators."""

    def f(name: str) -> np.ndarray:
        return features[:, _F[name]] > 0

    labial = f("bilabial") | f("labiodental")
    dorsal = f("velar") | f("glottal")
    return np.select(
        [f("silence"), f("vowel") & f("rounded"), f("vowel"), labial, dorsal],
        [0, 4, 5, 1, 3],
        default=2,
    ).astype(int)
