"""One on-disk cache for tensors that take long to compute, keyed by everything that produced them.

An entry is one tensor file in the cache directory, named ``<name>-<digest of its key>.safetensors``,
that stores its key in full. The key is a JSON-able dict of everything that decides the content:
seeds, sizes, settings, the identity of the models used and the source code that computed it
(:func:`source_identity`). A run whose key differs in any field looks for another file and builds
its own entry beside the old one; a file under the right name that records another key (copied,
edited, or a digest collision) is refused with a ``ValueError`` naming the first field that
differs, never silently used or overwritten.

Jobs of one sweep often need the same missing entry at once: the first takes a lock file beside
the entry (``<entry>.lock``, holding its host and process id, :class:`FileLock`) and builds; the
others wait for the entry's file. A lock whose process is gone (same host) is taken over.
"""

from __future__ import annotations

import importlib
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from torch import Tensor

from hbni_infra.fingerprint import check_fingerprint, digest
from hbni_infra.tensorfile import load_tensors, save_tensors

KIND = "hbni_infra.CacheEntry"
_POLL_SECONDS = 1.0
_LAYOUT = "digested files"  # part of every entry's name: files of another layout are never looked up


def entry_path(cache_dir: str | os.PathLike, name: str, key: dict[str, Any]) -> Path:
    """Where the entry ``name`` with ``key`` lives in ``cache_dir`` (entries written before file digests have other
    names: they are built again beside the old files, never refused)."""
    return Path(cache_dir) / f"{name}-{digest(_LAYOUT, key)[:24]}.safetensors"


def load_entry(path: str | os.PathLike, key: dict[str, Any], what: str = "cache entry") -> dict[str, Tensor]:
    """The tensors of the entry at ``path``; refuses a file recording another key, naming the field."""
    tensors, meta = load_tensors(path, KIND)
    check_fingerprint(meta.get("key"), key, what, path)
    return tensors


def store_entry(path: str | os.PathLike, key: dict[str, Any], tensors: dict[str, Tensor]) -> Path:
    """Write the entry atomically (a reader never sees half a file)."""
    return save_tensors(path, KIND, tensors, {"key": key})


def source_identity(*modules: str) -> str:
    """Digest of the source files of ``modules`` (dotted names; a package counts with all its ``.py`` files)."""
    files: list[Path] = []
    for name in modules:
        module = importlib.import_module(name)
        if hasattr(module, "__path__"):  # a package
            for folder in module.__path__:
                files += sorted(Path(folder).rglob("*.py"))
        else:
            files.append(Path(module.__file__))
    return digest(*(str(f.name).encode() + b"\0" + f.read_bytes() for f in files))


class FileLock:
    """A lock file beside a cache entry: :meth:`acquire` creates it (host and process id) or fails."""

    def __init__(self, entry: str | os.PathLike) -> None:
        entry = Path(entry)
        self.path = entry.with_name(entry.name + ".lock")
        self.held = False

    def acquire(self) -> bool:
        """Take the lock; take over one whose process is gone. Returns whether this process holds it."""
        if self.held:
            return True
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:
                if not self._stale():
                    return False
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                fh.write(f"{socket.gethostname()} {os.getpid()}")
            self.held = True
            return True
        return False

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def _stale(self) -> bool:
        """Whether the lock was taken by a process of this host that no longer runs."""
        try:
            host, pid = self.path.read_text().split()
            if host != socket.gethostname():
                return False
            os.kill(int(pid), 0)
        except ProcessLookupError:
            return True
        except (OSError, ValueError):
            return False  # unreadable or being written: leave it
        return False


def wait_for_entry(path: Path, key: dict[str, Any], lock: FileLock, what: str) -> dict[str, Tensor] | None:
    """Wait while another process builds the entry: its tensors once written, or ``None`` once ``lock`` is
    ours (the builder is gone, or there was none)."""
    while not lock.acquire():
        if path.is_file():
            return load_entry(path, key, what)
        time.sleep(_POLL_SECONDS)
    if path.is_file():  # written between our check and taking the lock
        lock.release()
        return load_entry(path, key, what)
    return None


def cached(
    cache_dir: str | os.PathLike | None, name: str, key: dict[str, Any], compute: Callable[[], dict[str, Tensor]]
) -> tuple[dict[str, Tensor], Path | None, bool]:
    """Tensors for ``key``: from ``cache_dir`` when a run with the same key stored them, else from ``compute()``
    (then stored; one process of a sweep computes, the others wait for it). ``cache_dir=None`` always computes.

    Returns:
        the tensors, the entry's file (``None`` without a cache) and whether they came from it.
    """
    if cache_dir is None:
        return compute(), None, False
    path = entry_path(cache_dir, name, key)
    if path.is_file():
        return load_entry(path, key, name), path, True
    lock = FileLock(path)
    found = wait_for_entry(path, key, lock, name)
    if found is not None:
        return found, path, True
    try:
        tensors = compute()
        store_entry(path, key, tensors)
    finally:
        lock.release()
    return tensors, path, False
