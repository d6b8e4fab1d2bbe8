"""A folder of data derived from a corpus (alignments, features): JSON and npz files only.

The default folder is ``~/.cache/vispeech/<corpus-name>-<content hash>``; the environment
variable ``VISPEECH_CACHE`` replaces ``~/.cache/vispeech``. Every file is written atomically,
so an interrupted job never leaves a half-written entry; nothing is ever pickled.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, cache_root

_KEY = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*$")


def content_hash(files: Iterable[Path], root: Path) -> str:
    """12 hex digits summarising the listing of ``files`` (path relative to ``root`` and size).

    Adding, removing, renaming or resizing a file changes it; touching one does not.
    """
    digest = hashlib.sha1()
    for path in sorted(Path(f) for f in files):
        digest.update(f"{path.relative_to(root).as_posix()}\t{path.stat().st_size}\n".encode())
    return digest.hexdigest()[:12]


class CorpusCache:
    """Derived data of one corpus, stored under ``folder`` by key (``"align/bbaf2n"``).

    Keys are slash-separated names of letters, digits, ``_``, ``.`` and ``-``; an entry is
    ``<folder>/<key>.json`` or ``<folder>/<key>.npz``.
    """

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder).expanduser()

    @classmethod
    def for_corpus(cls, name: str, digest: str, folder: str | os.PathLike | None = None) -> CorpusCache:
        """The cache of corpus ``name`` with content hash ``digest``, or exactly ``folder`` if given."""
        if folder is not None:
            return cls(folder)
        return cls(cache_root() / f"{name}-{digest}")

    def __repr__(self) -> str:
        return f"CorpusCache({str(self.folder)!r})"

    def _path(self, key: str, suffix: str) -> Path:
        if not _KEY.match(key) or ".." in key.split("/"):
            raise VispeechError(f"invalid cache key {key!r}")
        return self.folder / f"{key}{suffix}"

    def read_json(self, key: str) -> dict | list | None:
        """The JSON entry ``key``, or ``None`` if absent or unreadable."""
        try:
            return json.loads(self._path(key, ".json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def write_json(self, key: str, data: dict | list) -> Path:
        """Store ``data`` as the JSON entry ``key``; returns its path."""
        path = self._path(key, ".json")
        with atomic_output_file(path) as tmp:
            tmp.write_text(json.dumps(data, ensure_ascii=False), encoding="utf-8")
        return path

    def read_arrays(self, key: str) -> dict[str, np.ndarray] | None:
        """The arrays of the npz entry ``key``, or ``None`` if absent or unreadable."""
        try:
            with np.load(self._path(key, ".npz"), allow_pickle=False) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError):
            return None

    def write_arrays(self, key: str, arrays: dict[str, np.ndarray]) -> Path:
        """Store named numeric ``arrays`` as the npz entry ``key``; returns its path."""
        path = self._path(key, ".npz")
        arrays = {name: np.asarray(a) for name, a in arrays.items()}
        for name, a in arrays.items():
            if a.dtype.hasobject:
                raise VispeechError(f"cache entry {key!r}: array {name!r} is not numeric")
        with atomic_output_file(path) as tmp, open(tmp, "wb") as f:
            # object arrays are refused above, so pickling is moot; naming allow_pickle keeps the
            # arrays (**kwds) from being matched against it
            np.savez(f, allow_pickle=False, **arrays)
        return path
