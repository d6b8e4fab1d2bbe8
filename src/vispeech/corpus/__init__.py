"""Corpora of recorded speech with face tracks: the corpus type, readers, splits and cache.

Two layouts are read: the GRID audio-visual corpus (:func:`read_grid`) and a folder of Live
Link Face takes (:func:`read_takes`); :func:`read_corpus` tells them apart.
"""

from vispeech.corpus.alignment import align_corpus
from vispeech.corpus.articulation import ARTICULATORY_CHANNELS, articulatory_parameters, with_articulatory_tracks
from vispeech.corpus.cache import CorpusCache
from vispeech.corpus.corpus import SPLITS, Corpus, CorpusWarning, Utterance, split_of
from vispeech.corpus.grid import read_grid
from vispeech.corpus.read import read_corpus
from vispeech.corpus.takes import read_takes

__all__ = [
    "ARTICULATORY_CHANNELS",
    "with_articulatory_tracks",
    "SPLITS",
    "Corpus",
    "CorpusCache",
    "CorpusWarning",
    "Utterance",
    "align_corpus",
    "articulatory_parameters",
    "read_corpus",
    "read_grid",
    "read_takes",
    "split_of",
]
