"""The server's utterance cache: audio and animation of spoken texts in one SQLite file.

An entry is keyed by everything that changes the result: text, language, espeak voice,
speaking rate, model name, model version and frame rate. Its id (32 hex digits of the
key's SHA-256) names the audio at ``/api/audio/<id>.wav``. SQLite commits each write in a
transaction, so a crash never leaves half an entry; one lock serialises the connection, so
the cache is safe to share between threads. The oldest-used entries go when there are more
than ``max_entries``.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from vispeech.corpus.cache import cache_root
from vispeech.errors import VispeechError


def default_cache_path() -> Path:
    """``serve.sqlite3`` in the user cache folder (``$VISPEECH_CACHE`` or ``~/.cache/vispeech``)."""
    return cache_root() / "serve.sqlite3"


@dataclass(frozen=True)
class CacheKey:
    """What an utterance depends on."""

    text: str
    language: str
    voice: str
    rate: float
    model: str
    model_version: str
    fps: float

    @property
    def id(self) -> str:
        """32 hex digits naming the entry (and its audio URL)."""
        fields = [self.text, self.language, self.voice, float(self.rate),
                  self.model, self.model_version, float(self.fps)]
        return hashlib.sha256(json.dumps(fields, ensure_ascii=False).encode()).hexdigest()[:32]


@dataclass(frozen=True)
class CachedUtterance:
    """One cache entry: its id, the WAV file's bytes and the animation JSON text."""

    id: str
    wav: bytes
    animation: str


_SCHEMA = """
CREATE TABLE IF NOT EXISTS utterances (
    id TEXT PRIMARY KEY,
    text TEXT NOT NULL, language TEXT NOT NULL, voice TEXT NOT NULL, rate REAL NOT NULL,
    model TEXT NOT NULL, model_version TEXT NOT NULL, fps REAL NOT NULL,
    wav BLOB NOT NULL, animation TEXT NOT NULL,
    created REAL NOT NULL, used REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS utterances_used ON utterances (used);
"""


class UtteranceCache:
    """Spoken utterances by :class:`CacheKey` in the SQLite file ``path`` (created if missing).

    ``path`` ``None`` means :func:`default_cache_path`; ``":memory:"`` keeps the cache in memory.
    """

    def __init__(self, path: str | os.PathLike | None = None, max_entries: int = 10_000) -> None:
        if max_entries < 1:
            raise VispeechError(f"max_entries must be at least 1, got {max_entries}")
        if path is None:
            self.path: Path | None = default_cache_path()
        else:
            self.path = None if str(path) == ":memory:" else Path(path).expanduser()
        self.max_entries = max_entries
        self._lock = threading.Lock()
        try:
            if self.path is not None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(":memory:" if self.path is None else self.path, check_same_thread=False)
            if self.path is not None:
                self._db.execute("PRAGMA journal_mode=WAL")
            self._db.executescript(_SCHEMA)
        except (OSError, sqlite3.Error) as exc:
            raise VispeechError(f"cannot open the cache {self.path or ':memory:'}: {exc}") from None

    def __repr__(self) -> str:
        return f"UtteranceCache({str(self.path or ':memory:')!r})"

    def __len__(self) -> int:
        with self._lock:
            return self._db.execute("SELECT COUNT(*) FROM utterances").fetchone()[0]

    def get(self, key: CacheKey) -> CachedUtterance | None:
        """The entry for ``key`` (marked as just used), or ``None``."""
        return self._lookup(key.id, touch=True)

    def audio(self, entry_id: str) -> bytes | None:
        """The WAV bytes of entry ``entry_id``, or ``None``."""
        entry = self._lookup(entry_id, touch=False)
        return None if entry is None else entry.wav

    def put(self, key: CacheKey, wav: bytes, animation: str) -> CachedUtterance:
        """Store (or replace) the entry for ``key``; evicts the least recently used beyond ``max_entries``."""
        now = time.time()
        row = (key.id, key.text, key.language, key.voice, float(key.rate), key.model, key.model_version,
               float(key.fps), sqlite3.Binary(wav), animation, now, now)
        with self._lock, self._db:
            self._db.execute("INSERT OR REPLACE INTO utterances VALUES (?,?,?,?,?,?,?,?,?,?,?,?)", row)
            self._db.execute(
                "DELETE FROM utterances WHERE id IN (SELECT id FROM utterances ORDER BY used DESC LIMIT -1 OFFSET ?)",
                (self.max_entries,),
            )
        return CachedUtterance(key.id, wav, animation)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _lookup(self, entry_id: str, touch: bool) -> CachedUtterance | None:
        with self._lock, self._db:
            row = self._db.execute("SELECT wav, animation FROM utterances WHERE id = ?", (entry_id,)).fetchone()
            if row is None:
                return None
            if touch:
                self._db.execute("UPDATE utterances SET used = ? WHERE id = ?", (time.time(), entry_id))
        return CachedUtterance(entry_id, bytes(row[0]), row[1])
