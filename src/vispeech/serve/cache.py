"""The server's utterance cache: audio and animation of spoken texts in one SQLite file.

An entry is keyed by everything that changes the result: text, language, espeak voice,
speaking rate, model name, model version, frame rate and output scale. Its id, which names the audio at
``/api/audio/<id>.wav``, is 32 hex digits of an HMAC-SHA256 of the key under a random secret
kept in the file's ``meta`` table: the same request finds the same entry (also after a
restart), but nobody without the file can compute the id of a text, so the audio of what
others had spoken cannot be probed for. SQLite commits each write in a transaction, so a
crash never leaves half an entry; one lock serialises the connection, so the cache is safe
to share between threads. The least recently used entries go when there are more than
``max_entries`` or their audio and animation hold more than ``max_bytes``.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from vispeech.errors import VispeechError
from vispeech.files import cache_root


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
    scale: str
    """The output scale: a digest of its gains (:meth:`vispeech.serve.service.SpeechService.scale`)."""

    def canonical(self) -> bytes:
        """The key's fields as canonical JSON (what its id is computed from)."""
        fields = [
            self.text,
            self.language,
            self.voice,
            float(self.rate),
            self.model,
            self.model_version,
            float(self.fps),
            self.scale,
        ]
        return json.dumps(fields, ensure_ascii=False).encode("utf-8", "surrogatepass")

    def id(self, secret: bytes) -> str:
        """32 hex digits naming the entry (and its audio URL) under the cache's ``secret``."""
        return hmac.new(secret, self.canonical(), hashlib.sha256).hexdigest()[:32]


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
    model TEXT NOT NULL, model_version TEXT NOT NULL, fps REAL NOT NULL, scale TEXT NOT NULL,
    wav BLOB NOT NULL, animation TEXT NOT NULL,
    created REAL NOT NULL, used REAL NOT NULL, size INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS utterances_used ON utterances (used);
CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT NOT NULL);
"""
_SCHEMA_VERSION = "3"
"""2: ids are HMACs under the file's secret, rows know their size; 3: rows know their output scale
(files of older versions are emptied)."""


class UtteranceCache:
    """Spoken utterances by :class:`CacheKey` in the SQLite file ``path`` (created if missing).

    ``path`` ``None`` means :func:`default_cache_path`; ``":memory:"`` keeps the cache in memory.
    At most ``max_entries`` entries and ``max_bytes`` bytes of audio and animation are kept
    (least recently used go first; an entry just written stays even when it alone is larger).
    """

    def __init__(
        self, path: str | os.PathLike | None = None, max_entries: int = 10_000, max_bytes: int = 512 * 1024 * 1024
    ) -> None:
        if max_entries < 1:
            raise VispeechError(f"max_entries must be at least 1, got {max_entries}")
        if max_bytes < 1:
            raise VispeechError(f"max_bytes must be at least 1, got {max_bytes}")
        self.max_bytes = max_bytes
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
            self._migrate()
            self._db.executescript(_SCHEMA)
            self.secret = self._secret()
        except (OSError, sqlite3.Error) as exc:
            raise VispeechError(f"cannot open the cache {self.path or ':memory:'}: {exc}") from None

    def __repr__(self) -> str:
        return f"UtteranceCache({str(self.path or ':memory:')!r})"

    def __len__(self) -> int:
        with self._lock:
            return self._db.execute("SELECT COUNT(*) FROM utterances").fetchone()[0]

    def _migrate(self) -> None:
        """Empty a cache file of an older layout (its ids could be guessed; rows had no size)."""
        tables = {row[0] for row in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        version = None
        if "meta" in tables:
            row = self._db.execute("SELECT value FROM meta WHERE name = 'schema'").fetchone()
            version = row and row[0]
        if "utterances" in tables and version != _SCHEMA_VERSION:
            with self._db:
                self._db.execute("DROP TABLE utterances")

    def _secret(self) -> bytes:
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)", (_SCHEMA_VERSION,))
            self._db.execute("INSERT OR IGNORE INTO meta VALUES ('secret', ?)", (secrets.token_hex(32),))
            return bytes.fromhex(self._db.execute("SELECT value FROM meta WHERE name = 'secret'").fetchone()[0])

    def entry_id(self, key: CacheKey) -> str:
        """The id of ``key``'s entry (and of its audio URL) in this cache."""
        return key.id(self.secret)

    def total_bytes(self) -> int:
        """Bytes of audio and animation held."""
        with self._lock:
            return self._db.execute("SELECT COALESCE(SUM(size), 0) FROM utterances").fetchone()[0]

    def get(self, key: CacheKey) -> CachedUtterance | None:
        """The entry for ``key`` (marked as just used), or ``None``."""
        return self._lookup(self.entry_id(key), touch=True)

    def audio(self, entry_id: str) -> bytes | None:
        """The WAV bytes of entry ``entry_id``, or ``None``."""
        entry = self._lookup(entry_id, touch=False)
        return None if entry is None else entry.wav

    def put(self, key: CacheKey, wav: bytes, animation: str) -> CachedUtterance:
        """Store (or replace) the entry for ``key``; evicts the least recently used beyond
        ``max_entries`` entries or ``max_bytes`` bytes."""
        now = time.time()
        entry_id = self.entry_id(key)
        size = len(wav) + len(animation.encode("utf-8", "surrogatepass"))
        row = (
            entry_id,
            key.text,
            key.language,
            key.voice,
            float(key.rate),
            key.model,
            key.model_version,
            float(key.fps),
            key.scale,
            sqlite3.Binary(wav),
            animation,
            now,
            now,
            size,
        )
        with self._lock, self._db:
            self._db.execute("INSERT OR REPLACE INTO utterances VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)", row)
            self._db.execute(
                "DELETE FROM utterances WHERE id IN (SELECT id FROM utterances ORDER BY used DESC LIMIT -1 OFFSET ?)",
                (self.max_entries,),
            )
            total = self._db.execute("SELECT COALESCE(SUM(size), 0) FROM utterances").fetchone()[0]
            if total > self.max_bytes:
                doomed = []
                for old_id, old_size in self._db.execute(
                    "SELECT id, size FROM utterances WHERE id != ? ORDER BY used ASC", (entry_id,)
                ):
                    if total <= self.max_bytes:
                        break
                    doomed.append((old_id,))
                    total -= old_size
                self._db.executemany("DELETE FROM utterances WHERE id = ?", doomed)
        return CachedUtterance(entry_id, wav, animation)

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
