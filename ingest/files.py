"""Atomic file writes shared by every layer (CALIB.json, PX4 .params, replay tables, simulated logs).

A reader never sees a half-written file: the content goes to a temporary file in the target's directory (same
file system, so the rename is atomic), is flushed to disk with ``fsync``, then moved over the target with one
``os.replace``. If writing fails the temporary file is removed and the target keeps its previous content.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text"]


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Create or replace ``path`` atomically with whatever ``write`` puts in the file it is given.

    Parameters
    ----------
    path : str or PathLike
        Target file; its directory must exist.
    write : callable
        ``write(temp_path)`` writes the complete content to ``temp_path`` (an existing, empty file beside ``path``
        named ``.<name>.<random>.tmp``), e.g. ``lambda p: frame.to_parquet(p)``. It may reopen and truncate it.

    Returns
    -------
    Path
        ``path``.

    Notes
    -----
    The temporary file is fsync'ed before the ``os.replace`` and the directory after it (where the platform
    allows). The new file gets the mode of the file it replaces, or ``0o666`` minus the umask for a new file (as a
    plain ``open`` would). On any exception from ``write`` (or the flush/rename), including KeyboardInterrupt, the
    temporary file is deleted, ``path`` is left untouched and the exception propagates.

    Raises
    ------
    FileNotFoundError
        When the directory of ``path`` does not exist (``filename`` is ``path``).
    NotADirectoryError
        When the parent of ``path`` is not a directory.
    """
    path = Path(path)
    directory = path.parent
    _check_directory(path)
    fd, name = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    temp = Path(name)
    try:
        write(temp)
        _fsync_file(temp)
        os.chmod(temp, _target_mode(path))
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    _fsync_directory(directory)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Create or replace ``path`` atomically with ``data`` (see :func:`atomic_write`); returns ``path``."""
    return atomic_write(path, lambda temp: temp.write_bytes(data))


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Create or replace ``path`` atomically with ``text`` encoded as ``encoding``, line endings written as given
    (no platform newline translation; see :func:`atomic_write`); returns ``path``."""
    return atomic_write_bytes(path, text.encode(encoding))


def _check_directory(path: Path) -> None:
    directory = path.parent
    if not directory.exists():
        raise FileNotFoundError(errno.ENOENT, f"directory {str(directory)!r} does not exist", str(path))
    if not directory.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, f"{str(directory)!r} is not a directory", str(path))


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDWR | getattr(os, "O_BINARY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(directory: Path) -> None:
    """Persist the rename (POSIX); a no-op where directories cannot be opened (Windows) or synced."""
    if not hasattr(os, "O_DIRECTORY"):
        return
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _target_mode(path: Path) -> int:
    """Permission bits for the new file: those of the file being replaced, else 0o666 minus the umask."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        return 0o666 & ~_umask()


def _umask() -> int:
    """The process umask, read without changing it where Linux exposes it, else set and restored at once."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
