"""Writing outputs so that a failure never leaves a file or folder half-written."""

from __future__ import annotations

import errno
import functools
import json
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vispeech import limits
from vispeech.errors import VispeechError

try:
    import fcntl
except ImportError:  # Windows: no flock, so no clean-up of killed runs' leftovers
    fcntl = None  # type: ignore[assignment]  # the optional-module idiom: checked for None before use


def cache_root() -> Path:
    """The folder vispeech keeps derived data in (corpus caches, the server's cache, Whisper
    copies): ``$VISPEECH_CACHE`` or ``~/.cache/vispeech``."""
    configured = os.environ.get("VISPEECH_CACHE")
    return Path(configured).expanduser() if configured else Path.home() / ".cache" / "vispeech"


def read_bytes(path: str | os.PathLike, what: str = "file", limit: int = limits.MAX_FILE_BYTES) -> bytes:
    """The bytes of ``path``, a regular file (not a folder, FIFO or device, also through a
    symlink) of at most ``limit`` bytes: checked with one ``stat`` before it is opened, and at
    most ``limit + 1`` bytes are ever read. Raises :class:`VispeechError` naming ``what``."""
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
    return data


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
    data = read_bytes(path, what, limit)
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


def read_json(path: str | os.PathLike, what: str = "JSON file") -> dict:
    """The JSON object in ``path`` (read by :func:`read_text`, parsed by
    :func:`vispeech.limits.parse_json`); :class:`VispeechError` if it is not an object."""
    data = limits.parse_json(read_text(path, what), str(path))
    if not isinstance(data, dict):
        raise VispeechError(f"{path}: expected a JSON object")
    return data


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# -- whole-folder replacement ------------------------------------------------------------------
#
# Everything a run leaves beside its target while it works is named ``.vispeech-<key>.<role>``
# in the target's parent folder: ``<key>.lock`` (a small file naming the target, flock-ed by the
# live run), ``<key>.tmp/`` (the folder being written), ``<key>.new/`` (the same folder once
# complete: every file fsync-ed), ``<key>.old/`` (the replaced folder, where the
# exchange is unavailable), and ``<key>.part`` (a file being written by atomic_output_file,
# flock-ed while live). Runs take an flock on the parent folder itself while they clean up and
# create their entries, so a cleaner never sees another run's entries before they are locked.

_PREFIX = ".vispeech-"
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
_SYS_RENAMEAT2 = {"x86_64": 316, "amd64": 316, "aarch64": 276, "arm64": 276}
_swap_function: Any = None
_cleaned: set[str] = set()
_staging: set[str] = set()  # folders atomic_output_dir is writing in this process


def _exchange_function() -> Any:
    """The C function that swaps two paths in one step, or ``False`` where there is none."""
    global _swap_function
    if _swap_function is None:
        _swap_function = False
        try:
            import ctypes
            import platform

            libc = ctypes.CDLL(None, use_errno=True)
            if hasattr(libc, "renameat2"):  # Linux, glibc 2.28+
                func = libc.renameat2
                func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]

                def swap(a: bytes, b: bytes) -> int:
                    return func(_AT_FDCWD, a, _AT_FDCWD, b, _RENAME_EXCHANGE)

                _swap_function = swap
            elif hasattr(libc, "renamex_np"):  # macOS
                func = libc.renamex_np
                func.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint]

                def swap(a: bytes, b: bytes) -> int:
                    return func(a, b, 2)  # RENAME_SWAP

                _swap_function = swap
            elif sys.platform.startswith("linux") and platform.machine().lower() in _SYS_RENAMEAT2:
                number = _SYS_RENAMEAT2[platform.machine().lower()]
                func = libc.syscall
                func.restype = ctypes.c_long

                def swap(a: bytes, b: bytes) -> int:
                    at = ctypes.c_int(_AT_FDCWD)
                    return func(ctypes.c_long(number), at, a, at, b, ctypes.c_uint(_RENAME_EXCHANGE))

                _swap_function = swap
        except (OSError, AttributeError, TypeError):
            _swap_function = False
    return _swap_function


def _exchange(a: str, b: str) -> bool:
    """Swap the two existing paths ``a`` and ``b`` in one step (``renameat2(RENAME_EXCHANGE)``).

    Returns False where the system or file system cannot (then nothing changed); raises
    :class:`OSError` for any other failure.
    """
    import ctypes
    import errno

    func = _exchange_function()
    if not func:
        return False
    if func(os.fsencode(a), os.fsencode(b)) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(code, os.strerror(code), a)


def _try_lock(fd: int, block: bool = False) -> bool | None:
    """flock ``fd``: True if taken, False if another process holds it, None if locks do not work here."""
    if fcntl is None:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if block else fcntl.LOCK_NB))
        return True
    except BlockingIOError:
        return False
    except OSError:
        return None


@contextmanager
def _parent_lock(parent: Path) -> Iterator[bool]:
    """Hold an flock on folder ``parent`` (yields whether it works here)."""
    try:
        fd = os.open(parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        yield False
        return
    try:
        yield bool(_try_lock(fd, block=True))
    finally:
        os.close(fd)  # closing drops the lock


def _fsync(path: str | os.PathLike, directory: bool = False) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_tree(folder: Path, *, folders: bool) -> None:
    """fsync every file under ``folder`` (``folders``: every folder instead, then ``folder`` itself)."""
    for root, dirs, files in os.walk(folder):
        for name in dirs if folders else files:
            _fsync(os.path.join(root, name), directory=folders)
    if folders:
        _fsync(folder, directory=True)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def _clean_stale(parent: Path) -> None:
    """Remove what crashed runs left in ``parent`` (call with the parent's flock held).

    Only entries named ``.vispeech-*.lock`` / ``.vispeech-*.part`` that no live process holds
    are touched, with the ``.tmp``, ``.new`` and ``.old`` folders of the same key. Where a
    lock names a target that is missing (a run was killed between its two renames, or before
    its first), the complete new folder, else the old one, is renamed back onto it first.
    """
    try:
        names = sorted(n for n in os.listdir(parent) if n.startswith(_PREFIX))
    except OSError:
        return
    for name in names:
        if not name.endswith((".lock", ".part")):
            continue
        entry = parent / name
        try:
            fd = os.open(entry, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0))
        except OSError:
            continue
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode) or _try_lock(fd) is not True:
                continue
            if name.endswith(".part"):
                entry.unlink()
                continue
            key = name[: -len(".lock")]
            try:
                target = json.loads(os.read(fd, 4096).decode("utf-8"))["target"]
            except (OSError, ValueError, KeyError, TypeError):
                target = None
            if isinstance(target, str) and target and "/" not in target and target not in (".", ".."):
                goal = parent / target
                if not os.path.lexists(goal):
                    for role in (".new", ".old"):
                        candidate = parent / f"{key}{role}"
                        if candidate.is_dir() and not candidate.is_symlink():
                            os.rename(candidate, goal)
                            _fsync(parent, directory=True)
                            break
            for role in (".tmp", ".new", ".old"):
                _remove(parent / f"{key}{role}")
            entry.unlink()
        except OSError:
            pass
        finally:
            os.close(fd)


def _refuse_foreign(target: Path, allowed: set[str], shown: Path) -> None:
    """:class:`VispeechError` when folder ``target`` holds names neither in ``allowed`` nor vispeech's own leftovers."""
    foreign = sorted(n for n in os.listdir(target) if n not in allowed and not n.startswith(_PREFIX))
    if foreign:
        more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        raise VispeechError(
            f"output folder {shown} holds files vispeech did not write "
            f"({', '.join(foreign[:3])}{more}): empty it or choose another folder"
        )


def check_output_dir(
    path: str | os.PathLike, *, replaces: Iterable[str] = (), inputs: Iterable[str | os.PathLike] = ()
) -> None:
    """Refuse now, with :class:`VispeechError`, a folder that :func:`atomic_output_dir` with
    ``replaces`` would refuse after the work: a path that is not a folder, read-only, the root,
    a mount point or above the current folder, or a folder holding files other than ``replaces``
    (and vispeech's leftovers). Call it before long work; the swap checks again. Also refused:
    a folder holding one of the work's ``inputs``, which the swap would remove with the folder
    (a ``phones.TextGrid`` edited in the folder ``say`` wrote, animated back into it)."""
    target = _checked_target(path)
    for given in inputs:
        if target in Path(os.path.realpath(given)).parents:
            raise VispeechError(
                f"output folder {path} holds the input {given} and is replaced as a whole: give another folder"
            )
    if target.is_dir():
        _refuse_foreign(target, set(replaces), Path(path))


def _checked_target(path: str | os.PathLike) -> Path:
    """The real path of output folder ``path``, refused when it cannot be replaced as a whole."""
    target = Path(os.path.realpath(path))
    shown = Path(path)
    if target == target.parent:
        raise VispeechError(f"cannot replace output folder {shown}: it is the root folder")
    if os.path.lexists(target) and not target.is_dir():
        raise VispeechError(f"output path {shown} exists and is not a folder")
    if target.is_dir() and not os.access(target, os.W_OK):
        raise VispeechError(f"cannot write to output folder {shown}: Permission denied")
    cwd = Path(os.path.realpath(os.getcwd()))
    if cwd == target or target in cwd.parents:
        raise VispeechError(f"output folder {shown} holds the current folder: give another folder")
    if os.path.ismount(target):
        raise VispeechError(
            f"output folder {shown} is a mount point and cannot be replaced as a whole: give a folder inside it"
        )
    return target


@contextmanager
def atomic_output_dir(path: str | os.PathLike, *, replaces: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a fresh folder to write into; when the block succeeds it replaces ``path`` as a whole.

    The folder is made beside ``path`` (same parent, so renames are atomic). When the block
    ends without an error every file in it is fsync-ed, and it is swapped with ``path`` in one
    step (Linux ``renameat2(RENAME_EXCHANGE)``, macOS ``renamex_np``); the old folder is then
    removed. A kill at any moment leaves ``path`` as the old complete folder or the new
    complete one, never a mix, and never files of two runs side by side; so does a power cut,
    since the new folder is on disk, whole, before the swap (the file systems that exchange
    two paths journal their metadata: a file's fsync makes its name durable too, and the swap
    reaches the disk with their next commit, in order with the old folder's removal). Where
    no exchange exists the old folder is renamed aside and the new one into place, with the
    new folder, the lock naming the target and the swap each fsync-ed before the next step; a
    kill between the two renames leaves ``path`` missing until the next run into the same
    parent folder, which puts the complete new (else old) folder back; so does a first run
    (no old folder), with the new folders fsync-ed before it shows them. Every run first
    removes what killed runs left in the parent (only ``.vispeech-<key>.*`` entries whose lock
    no live process holds; see ``_clean_stale``). A block that raises leaves ``path`` untouched.

    An existing folder is replaced only when everything in it is named like an entry of the
    new folder or one of ``replaces`` (the names this kind of folder holds), or is a
    ``.vispeech-`` leftover: a folder holding other files (a user's) is never destroyed; the
    run stops with :class:`VispeechError` instead. Symlinks in ``path`` are followed: the
    folder they lead to is replaced. Raises :class:`VispeechError` when ``path`` exists and is
    not a folder, is read-only, is a mount point, is the current folder or one above it, or
    its parent cannot be written (the new folder is made there).
    """
    staged = _begin(path, set())
    try:
        yield staged.staging
        _fsync_tree(staged.staging, folders=False)  # whole on disk before anything points to it (_swap)
        _finish(staged, replaces)
    finally:
        _release(staged)


def write_output_dirs(
    paths: Sequence[str | os.PathLike], write: Callable[[int, Path], None], *, replaces: Iterable[str] = ()
) -> list[VispeechError | None]:
    """:func:`atomic_output_dir` for many folders at once: ``write(i, folder)`` fills a fresh
    folder that then replaces ``paths[i]``, with the same promise for each (old or new, whole,
    after a kill or a power cut). The new files are made durable together before any swap: one
    ``syncfs`` of each file system they are on where Linux has it, else an fsync of each file.

    Returns, per path, ``None`` or the :class:`VispeechError` that stopped it (from ``write`` or
    refusing the folder): that folder is left as it was, the others are written all the same.
    """
    names, n = tuple(replaces), len(paths)
    chunks = [range(first, min(first + _FOLDERS_AT_ONCE, n)) for first in range(0, n, _FOLDERS_AT_ONCE)]
    return [error for chunk in chunks for error in _write_dirs(paths, chunk, write, names)]


_FOLDERS_AT_ONCE = 256
"""Folders :func:`write_output_dirs` has open at a time (each holds its lock file open)."""


def _write_dirs(
    paths: Sequence[str | os.PathLike], indices: range, write: Callable[[int, Path], None], replaces: tuple[str, ...]
) -> list[VispeechError | None]:
    """:func:`write_output_dirs` of ``paths[i]`` for ``i`` in ``indices``, made durable together."""
    errors: list[VispeechError | None] = [None] * len(indices)
    staged: list[_Staged | None] = [None] * len(indices)
    cleaned: set[Path] = set()
    try:
        for j, i in enumerate(indices):
            try:
                begun = staged[j] = _begin(paths[i], cleaned)
                write(i, begun.staging)
            except VispeechError as exc:
                errors[j] = exc
        written = [(j, s) for j, s in enumerate(staged) if s is not None and errors[j] is None]
        _make_durable([s.staging for _, s in written])
        for j, s in written:
            try:
                _finish(s, replaces)
            except VispeechError as exc:
                errors[j] = exc
    finally:
        for left in staged:
            if left is not None:
                _release(left)
    return errors


@dataclass(frozen=True)
class _Staged:
    """A folder being written beside its target as ``<key>.tmp``, locked by ``<key>.lock``."""

    target: Path
    shown: Path
    key: str
    lock_fd: int

    @property
    def staging(self) -> Path:
        return Path(f"{self.key}.tmp")


def _begin(path: str | os.PathLike, cleaned: set[Path]) -> _Staged:
    """Check ``path``, make its parent and clean what killed runs left there (unless the parent is
    in ``cleaned``, where it is added) and make the locked staging folder for it."""
    target, shown = _checked_target(path), Path(path)
    parent = target.parent
    lock_fd = None
    try:
        if parent not in cleaned:
            parent.mkdir(parents=True, exist_ok=True)
        with _parent_lock(parent) as locked:
            if locked and parent not in cleaned:
                _clean_stale(parent)
            cleaned.add(parent)
            lock_fd, lock_name = tempfile.mkstemp(prefix=_PREFIX, suffix=".lock", dir=parent)
            _try_lock(lock_fd)
            os.write(lock_fd, json.dumps({"target": target.name}).encode("utf-8"))  # restored by this name
            staged = _Staged(target, shown, lock_name[: -len(".lock")], lock_fd)
            os.mkdir(staged.staging)
            _staging.add(str(staged.staging))
    except OSError as exc:
        if lock_fd is not None:
            os.close(lock_fd)
            _remove(Path(lock_name))
        raise VispeechError(f"cannot write to output folder {shown}: {exc.strerror or exc}") from None
    return staged


def _finish(staged: _Staged, replaces: Iterable[str]) -> None:
    """Swap the staging folder, its files durable already, in at the target; remove the old one."""
    complete, aside = Path(f"{staged.key}.new"), Path(f"{staged.key}.old")
    try:
        os.rename(staged.staging, complete)
        old = _swap(complete, staged.target, aside, replaces, staged.shown, staged.lock_fd)
    except OSError as exc:
        raise VispeechError(f"cannot write to output folder {staged.shown}: {exc.strerror or exc}") from None
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _release(staged: _Staged) -> None:
    """Remove what is left of a staging folder (the old folder put back where the swap failed) and its lock."""
    _staging.discard(str(staged.staging))
    target, complete, aside = staged.target, Path(f"{staged.key}.new"), Path(f"{staged.key}.old")
    if aside.is_dir() and not os.path.lexists(target):
        try:
            os.rename(aside, target)  # never lose the old folder
        except OSError:
            pass
    for leftover in (staged.staging, complete, aside):
        if leftover.exists() and leftover != target and (leftover != aside or os.path.lexists(target)):
            shutil.rmtree(leftover, ignore_errors=True)
    _remove(Path(f"{staged.key}.lock"))
    os.close(staged.lock_fd)


def _make_durable(folders: Sequence[Path]) -> None:
    """Every file in ``folders`` on disk: for several folders one ``syncfs`` per file system where
    Linux has it, else an fsync of each file."""
    syncfs = _syncfs_function() if len(folders) > 1 else None
    by_device: dict[int, list[Path]] = {}
    for folder in folders:
        by_device.setdefault(os.stat(folder).st_dev, []).append(folder)
    for group in by_device.values():
        if syncfs is None or not syncfs(group[0]):
            for folder in group:
                _fsync_tree(folder, folders=False)


@functools.cache
def _syncfs_function() -> Callable[[Path], bool] | None:
    """Linux's ``syncfs`` (every file of one file system to disk in one call) as a function of a
    folder on it that says whether it worked, or ``None`` where there is none."""
    try:
        import ctypes

        func = ctypes.CDLL(None, use_errno=True).syncfs
    except (OSError, AttributeError, TypeError):
        return None
    func.argtypes = [ctypes.c_int]

    def syncfs(folder: Path) -> bool:
        try:
            fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        except OSError:
            return False
        worked = func(fd) == 0
        os.close(fd)
        return bool(worked)

    return syncfs


def _swap(complete: Path, target: Path, aside: Path, replaces: Iterable[str], shown: Path, lock_fd: int) -> Path | None:
    """Put the folder ``complete`` at ``target``; the old folder's path afterwards (to remove), if
    there was one. A folder another run puts at ``target`` between the check and the rename is
    replaced like any existing one.

    Every file in ``complete`` is fsync-ed already: where the exchange works (journaling file
    systems: ext4, XFS, Btrfs, F2FS; APFS), that makes their names durable too, and the swap
    reaches the disk in order with what follows it. Elsewhere the new folders are fsync-ed
    before the rename that shows them, the lock (``lock_fd``, naming the target) before the old
    folder leaves the target, and the parent folder after the new one is in place, so that a
    power cut never leaves the target missing for good."""
    while True:
        if target.is_dir():
            _refuse_foreign(target, set(os.listdir(complete)) | set(replaces), shown)
            os.chmod(complete, stat.S_IMODE(target.stat().st_mode))
            if _exchange(str(complete), str(target)):
                return complete  # the old folder now lies where the new one was
            _fsync_tree(complete, folders=True)
            os.fsync(lock_fd)
            os.rename(target, aside)
            try:
                os.rename(complete, target)
            except OSError:
                os.rename(aside, target)  # put the old folder back
                raise
            _fsync(target.parent, directory=True)
            return aside
        os.chmod(complete, 0o777 & ~_umask())
        _fsync_tree(complete, folders=True)  # no exchange tried: the file system may need it
        try:
            os.rename(complete, target)
            return None
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST) or not target.is_dir():
                raise


def check_output_file(path: str | os.PathLike) -> None:
    """Refuse now, with :class:`VispeechError`, a file :func:`atomic_output_file` could not write
    after the work: a folder at ``path``, or a folder it would go in that cannot be written (tried
    with a file made and removed in the nearest one that exists). Call it before long work."""
    target = Path(path)
    if target.is_dir():
        raise VispeechError(f"output path {target} is a folder")
    existing = next(p for p in (target.parent.absolute(), *target.parent.absolute().parents) if os.path.lexists(p))
    try:
        if not existing.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR))
        fd, probe = tempfile.mkstemp(prefix=_PREFIX, suffix=".part", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise VispeechError(f"cannot write {target}: {exc.strerror or exc}") from None


@contextmanager
def atomic_output_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` when the block succeeds.

    The temporary file (``.vispeech-*.part`` in the same folder) is fsync-ed before the
    rename, so ``path`` is always the old complete file or the new complete one, after a kill
    or a power cut (the rename reaches the disk with the file system's next commit); a block
    that raises removes it, and what a killed run left is removed by the next write into that
    folder (once per process and folder; only files no live process holds). Inside a folder
    that :func:`atomic_output_dir` is writing, the file is written in place: nobody sees that
    folder before it is fsync-ed whole and swapped in.
    """
    target = Path(path)
    parent = target.parent
    if str(parent) in _staging or os.path.realpath(parent) in _staging:
        yield target
        return
    fd = None
    try:
        parent.mkdir(parents=True, exist_ok=True)
        with _parent_lock(parent) as locked:
            key = str(parent.resolve())
            if locked and key not in _cleaned:
                _cleaned.add(key)
                _clean_stale(parent)
            fd, tmp = tempfile.mkstemp(prefix=_PREFIX, suffix=".part", dir=parent)
            _try_lock(fd)
        os.chmod(tmp, 0o666 & ~_umask())
    except OSError as exc:
        if fd is not None:
            os.close(fd)
            _remove(Path(tmp))
        raise VispeechError(f"cannot write {target}: {exc.strerror or exc}") from None
    try:
        yield Path(tmp)
        _fsync(tmp)
        os.replace(tmp, target)
    finally:
        os.close(fd)
        if os.path.exists(tmp):
            os.unlink(tmp)
