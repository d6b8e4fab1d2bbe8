"""Writing outputs so that a failure never leaves a file or folder half-written."""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from vispeech import limits
from vispeech.errors import VispeechError


def read_text(path: str | os.PathLike, what: str = "file", limit: int = limits.MAX_FILE_BYTES) -> str:
    """The text of ``path`` (UTF-8 with or without BOM, UTF-16 with BOM, else Latin-1).

    The path is checked before anything is read: it must be a regular file (not a folder,
    FIFO or device, also through a symlink) of at most ``limit`` bytes
    (:data:`vispeech.limits.MAX_FILE_BYTES` by default), and at most ``limit + 1`` bytes are
    ever read. Raises :class:`VispeechError` naming ``what`` when the file is missing,
    unreadable, too large, not text (a NUL byte, UTF-16 with an odd byte count or bad
    surrogates) or blank.
    """
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise VispeechError(f"{what} not found: {path}") from None
    except (OSError, ValueError) as exc:
        raise VispeechError(f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise VispeechError(f"{what} {path} is {kind}")
    if info.st_size > limit:
        raise VispeechError(f"{what} {path} has {info.st_size} bytes; the limit is {limit}")
    try:
        with path.open("rb") as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise VispeechError(f"cannot read {path}: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise VispeechError(f"{what} {path} has more than {limit} bytes (the limit)")
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        if len(data) % 2:
            raise VispeechError(f"{what} {path} starts as UTF-16 but has an odd number of bytes ({len(data)})")
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError as exc:
            raise VispeechError(f"{what} {path} is not valid UTF-16 (byte {exc.start}: {exc.reason})") from None
    else:
        nul = data.find(b"\x00")
        if nul >= 0:
            raise VispeechError(f"{what} {path} is not a text file (a NUL byte at byte {nul})")
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = data.decode("latin-1")
    if "\x00" in text:
        raise VispeechError(f"{what} {path} is not a text file (a NUL character)")
    if not text.strip():
        raise VispeechError(f"{what} is empty: {path}")
    return text


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_output_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh staging folder; on success move its files into ``path``.

    Files are staged beside ``path`` and renamed into it only when the block ends without an
    error, so an interrupted job leaves ``path`` as it was. Raises :class:`VispeechError`
    when ``path`` cannot be created or written.
    """
    target = Path(path)
    try:
        target.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".vispeech-", dir=target))
    except OSError as exc:
        raise VispeechError(f"cannot write to output folder {target}: {exc.strerror or exc}") from None
    try:
        yield staging
        for item in sorted(staging.iterdir()):
            os.replace(item, target / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


@contextmanager
def atomic_output_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` when the block succeeds."""
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())
    except OSError as exc:
        raise VispeechError(f"cannot write {target}: {exc.strerror or exc}") from None
    try:
        yield Path(tmp)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
