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
others wait for the entry's file. The holder touches its lock every :data:`HEARTBEAT_SECONDS`, so a
lock tells whether someone still builds, on any host. A waiter breaks a lock, with a warning naming
its path, when it is stale: its process is gone (same host), or it was not touched for
:data:`STALE_SECONDS` (a dead process of another host, a lock left empty or unreadable by a crash).
It waits on a live lock at most ``timeout`` seconds (:data:`WAIT_SECONDS` by default), then raises a
``TimeoutError`` naming the lock, its holder and how to break it. No wait is silent or unbounded.
"""

from __future__ import annotations

import importlib
import logging
import os
import socket
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from torch import Tensor

from hbni_infra.checks import as_float
from hbni_infra.fingerprint import check_fingerprint, digest
from hbni_infra.tensorfile import load_tensors, save_tensors

KIND = "hbni_infra.CacheEntry"
log = logging.getLogger(__name__)
_POLL_SECONDS = 1.0
_LAYOUT = "digested files"  # part of every entry's name: files of another layout are never looked up
HEARTBEAT_SECONDS = 30.0
"""How often the holder of a lock touches it (a daemon thread, while it holds it)."""
STALE_SECONDS = 300.0
"""A lock untouched for this long is stale: its holder is gone (10 missed heartbeats)."""
WAIT_SECONDS = 6 * 3600.0
"""The longest a process waits for another's live lock by default (``timeout`` of :func:`cached`)."""


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
    """A lock file beside a cache entry: :meth:`acquire` creates it (host and process id) or fails; while held, a
    daemon thread touches it every :data:`HEARTBEAT_SECONDS` (its mtime says that the holder lives)."""

    def __init__(self, entry: str | os.PathLike) -> None:
        entry = Path(entry)
        self.path = entry.with_name(entry.name + ".lock")
        self.held = False
        self._stop = threading.Event()

    def acquire(self) -> bool:
        """Take the lock; break a stale one (with a warning naming it). Returns whether this process holds it."""
        if self.held:
            return True
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            except FileExistsError:
                judged = self._identity()
                reason = self.stale()
                if reason is None:
                    return False
                if self._identity() != judged:  # replaced meanwhile (another waiter broke it and took it)
                    continue
                warnings.warn(f"{self.path}: breaking a stale cache lock ({reason})", RuntimeWarning, stacklevel=2)
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                fh.write(f"{socket.gethostname()} {os.getpid()}")
            self.held = True
            self._stop = threading.Event()
            threading.Thread(target=self._heartbeat, args=(self._stop,), daemon=True, name="cache-lock").start()
            return True
        return False

    def release(self) -> None:
        if self.held:
            self._stop.set()
            self.path.unlink(missing_ok=True)
            self.held = False

    def _heartbeat(self, stop: threading.Event) -> None:
        while not stop.wait(HEARTBEAT_SECONDS):
            try:
                os.utime(self.path)
            except OSError:
                return

    def _identity(self) -> tuple[int, int] | None:
        """The lock file's inode and mtime (``None`` when there is none): which lock a judgement was about."""
        try:
            st = self.path.stat()
        except FileNotFoundError:
            return None
        return st.st_ino, st.st_mtime_ns

    def holder(self) -> str:
        """Who holds the lock, as its file says (``"unknown"`` for an empty or unreadable file)."""
        try:
            host, pid = self.path.read_text().split()
            return f"process {int(pid)} on host {host!r}"
        except (OSError, ValueError):
            return "unknown"

    def stale(self) -> str | None:
        """Why the lock (held by another) is stale, or ``None`` while its holder may live: a process of this
        host that no longer runs, or a file untouched for :data:`STALE_SECONDS` (empty or not)."""
        try:
            age = time.time() - self.path.stat().st_mtime
        except FileNotFoundError:
            return None  # released meanwhile: the next try takes it
        try:
            host, pid = self.path.read_text().split()
            if host == socket.gethostname():
                os.kill(int(pid), 0)
        except ProcessLookupError:
            return f"process {pid} of this host no longer runs"
        except (OSError, ValueError):
            if age > STALE_SECONDS:
                return f"empty or unreadable, untouched for {age:.0f} s"
            return None  # being written: leave it
        if age > STALE_SECONDS:
            return f"held by {self.holder()}, untouched for {age:.0f} s (its holder touches it every {HEARTBEAT_SECONDS:g} s)"
        return None


def wait_for_entry(
    path: Path, key: dict[str, Any], lock: FileLock, what: str, timeout: float = WAIT_SECONDS
) -> dict[str, Tensor] | None:
    """Wait while another process builds the entry: its tensors once written, or ``None`` once ``lock`` is
    ours (the builder is gone, or there was none). A stale lock is broken with a warning; a live one is waited
    on for at most ``timeout`` seconds, then ``TimeoutError`` names the lock and its holder. When the wait starts, a
    logged warning names the entry, the lock, its holder and the settings that bound the wait."""
    timeout = as_float("timeout", timeout, 0.0)
    deadline, told = time.monotonic() + timeout, False
    while not lock.acquire():
        if path.is_file():
            return load_entry(path, key, what)
        if not told:
            log.warning(
                "waiting for %s %s: its lock %s is held by %s, who builds it; waiting until it is written, at most "
                "%g s (timeout of hbni_infra.cache.cached, WAIT_SECONDS by default); a lock untouched for %g s "
                "(STALE_SECONDS) is broken as stale",
                what,
                path.name,
                lock.path,
                lock.holder(),
                timeout,
                STALE_SECONDS,
            )
            told = True
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(
                f"{lock.path}: waited {timeout:g} s for {what} {path.name}, built by {lock.holder()}; if no process "
                f"builds it any more, delete the lock file (or wait: a lock untouched for {STALE_SECONDS:g} s is broken)"
            )
        time.sleep(min(_POLL_SECONDS, left))
    if path.is_file():  # written between our check and taking the lock
        lock.release()
        return load_entry(path, key, what)
    return None


def cached(
    cache_dir: str | os.PathLike | None,
    name: str,
    key: dict[str, Any],
    compute: Callable[[], dict[str, Tensor]],
    timeout: float = WAIT_SECONDS,
) -> tuple[dict[str, Tensor], Path | None, bool]:
    """Tensors for ``key``: from ``cache_dir`` when a run with the same key stored them, else from ``compute()``
    (then stored; one process of a sweep computes, the others wait for it, at most ``timeout`` seconds, breaking
    a stale lock: see the module doc). ``cache_dir=None`` always computes.

    Returns:
        the tensors, the entry's file (``None`` without a cache) and whether they came from it.
    """
    timeout = as_float("timeout", timeout, 0.0)
    if cache_dir is None:
        return compute(), None, False
    path = entry_path(cache_dir, name, key)
    if path.is_file():
        return load_entry(path, key, name), path, True
    lock = FileLock(path)
    found = wait_for_entry(path, key, lock, name, timeout)
    if found is not None:
        return found, path, True
    try:
        tensors = compute()
        store_entry(path, key, tensors)
    finally:
        lock.release()
    return tensors, path, False
