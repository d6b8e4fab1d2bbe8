"""Writing outputs so that a failure never leaves a file or folder half-written."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from vispeech.errors import VispeechError


def read_text(path: str | os.PathLike, what: str = "file") -> str:
    """The text of ``path`` (UTF-8 with or without BOM, UTF-16 with BOM, else Latin-1).

    Raises :class:`VispeechError` naming ``what`` when the file is missing, unreadable or blank.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise VispeechError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise VispeechError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("utf-16") if data[:2] in (b"\xff\xfe", b"\xfe\xff") else data.decode("latin-1")
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
