"""Atomic file writes: a temporary file in the target directory, fsynced, renamed into place.

A crash never leaves half a file: readers see the old file or the new one. The temporary file is
created with mode ``0o666`` so the process umask applies exactly as it does to ``open(path, "w")``
(``0o644`` under umask 022), and the directory is fsynced after the rename so the new name is
durable too.
:func:`atomic_path` does the same for a writer that creates its own file or directory (a ROS bag).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and durably; returns the path.

    Raises:
        IsADirectoryError: ``path`` is an existing directory.
        NotADirectoryError: a parent of ``path`` is a file.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path: {str(path)!r} is a directory, expected a file path")
    make_parents(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)
    return path


def make_parents(path: str | os.PathLike) -> None:
    """Create the missing directories above ``path``; ``NotADirectoryError`` naming both paths when one of its
    parents is a file."""
    path = Path(path)
    for parent in path.parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise NotADirectoryError(
                    f"path: cannot write {str(path)!r}: its parent {str(parent)!r} is a file, expected a directory"
                )
            break
    path.parent.mkdir(parents=True, exist_ok=True)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically and durably; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _fsync_directory(directory: Path) -> None:
    """Make a rename inside ``directory`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A fresh path with ``path``'s name, for a writer that creates its own file or directory; moved to ``path``
    on success.

    For writers that must create the target themselves (a ROS bag is a directory a library makes, and names
    its files after it): the caller writes to the yielded path, which lies in a hidden staging directory
    beside ``path``; when the block ends without an error, every file under it is fsynced and it is renamed
    to ``path``; on an error it is removed and ``path`` is untouched.

    Raises:
        FileExistsError: ``path`` exists (an output is never overwritten).
        NotADirectoryError: a parent of ``path`` is a file.
    """
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"path: {str(path)!r} exists already")
    make_parents(path)
    staging = path.with_name(f".{path.name}.{secrets.token_hex(6)}.partial")
    staging.mkdir()
    try:
        yield staging / path.name
        written = staging / path.name
        for item in [written, *written.rglob("*")]:
            if item.is_file():
                with open(item, "rb+") as fh:
                    os.fsync(fh.fileno())
            elif item.is_dir():
                _fsync_directory(item)
        os.rename(written, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    _fsync_directory(path.parent)
