"""A run folder belongs to one run: a live run holds it, an earlier run's folder is replaced only when asked, and a
refused run changes nothing in it.

A run (or a ``-m`` sweep's parent, for the sweep's folder; or a sweep's job, for its own folder) claims its folder
before Hydra writes anything there (:class:`experiments.guard.RunGuard`, :class:`experiments.sweep.SweepGuard`):

* It holds an exclusive ``flock`` on ``<folder>/.run.lock`` for its life; the lock file names the holder (process
  id, host, start, command line). The kernel drops the lock when the process ends, however it ends, so a crashed
  run never blocks the folder; a run that ends removes the file (:meth:`Claim.release`).
* A folder that a live run holds is refused, naming that run.
* A folder that holds an earlier run or sweep (completed, failed, or stopped without finishing) is refused unless
  ``run.overwrite=true``; then its contents are removed before the new run starts, so that no file of the old run
  is mixed into the new one.
* A refused run writes, creates and removes nothing in the folder: it reads the status and tries the lock read-only.

Only the standard library: the signal handling that releases a claim as a run is stopped imports it first.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path

LOCK = ".run.lock"
"""The lock file a run holds in its folder."""
OVERWRITE = "run.overwrite"
"""The setting that lets a run replace an earlier run's folder."""


class FolderTaken(FileExistsError):
    """The folder is held by a live run, or holds an earlier run (the message says which, and what to do)."""


class Claim:
    """This process's hold on a run folder: an open, ``flock``-ed ``.run.lock``."""

    def __init__(self, folder: Path, fd: int) -> None:
        self.folder, self._fd = folder, fd

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Remove the lock file (while still holding it) and drop the lock; nothing when released already."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        with contextlib.suppress(OSError):
            if os.stat(self.folder / LOCK).st_ino == os.fstat(fd).st_ino:
                os.unlink(self.folder / LOCK)
        os.close(fd)
        with contextlib.suppress(ValueError):
            _held.remove(self)


_held: list[Claim] = []


def release_all() -> None:
    """Release every claim this process holds (a run ending by a signal)."""
    for held in list(_held):
        held.release()


def claim(folder: str | os.PathLike, overwrite: bool = False, check_previous: bool = True) -> Claim:
    """Claim ``folder`` for this process's run (create it if missing).

    Args:
        folder: the run's (or sweep's) folder.
        overwrite: replace an earlier run or sweep found there (its contents are removed first).
        check_previous: look for an earlier run at all (a sweep's job does not: its parent checked its folder, and
            Hydra has written the job's own ``.hydra`` there).

    Raises:
        FolderTaken: a live run holds ``folder``, or it holds an earlier run and ``overwrite`` is false; nothing
            in the folder was changed.
        ValueError: ``overwrite`` would remove the working directory or one above it.
    """
    folder = Path(folder).absolute()
    holder = live_holder(folder)
    if holder is not None:
        raise FolderTaken(f"{folder}: in use by a live {holder}; wait for it to end or run into another folder")
    if check_previous:
        _check_previous(folder, overwrite)
    folder.mkdir(parents=True, exist_ok=True)
    fd, created = _open_locked(folder)
    taken = Claim(folder, fd)
    try:
        if check_previous:  # again under the lock: a run may have ended here since
            _check_previous(folder, overwrite)
            if overwrite and previous_run(folder) is not None:
                _clear(folder)
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(_me()).encode() + b"\n", 0)
    except BaseException:
        if not created:  # a lock file left by a run that died: it stays as it was
            taken._fd = None
            os.close(fd)
        else:
            taken.release()
        raise
    _held.append(taken)
    return taken


def live_holder(folder: Path) -> str | None:
    """``"run (pid ..., host ..., since ...: command)"`` when a live process holds ``folder``'s lock, else ``None``
    (the lock is tried read-only: nothing is created)."""
    try:
        fd = os.open(folder / LOCK, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            return _describe_holder(fd)
        return None
    finally:
        os.close(fd)


def previous_run(folder: Path) -> str | None:
    """What an earlier run or sweep left in ``folder`` (``None``: nothing, or no folder)."""
    if not folder.is_dir():
        return None
    if (folder / "multirun.yaml").is_file():
        jobs = [p.name for p in folder.iterdir() if p.is_dir() and p.name.isdigit()]
        return f"an earlier sweep ({len(jobs)} job folders)"
    from experiments.runs.status import read_status  # loaded by then; not at import, when the command starts

    try:
        status = read_status(folder)
    except (OSError, ValueError):
        return "an earlier run whose status.json cannot be read"
    if status is not None and status["status"] == "running":
        return "a run that stopped without finishing (status.json says running; no live process holds it)"
    if status is not None:
        return f"a {status['status']} run"
    if (folder / ".hydra").is_dir():
        return "an earlier run that wrote no status.json"
    return None


def remove_stale_lock(folder: Path) -> None:
    """Remove ``folder``'s lock file when no live process holds it (a job that was killed)."""
    try:
        fd = os.open(folder / LOCK, os.O_RDWR)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with contextlib.suppress(OSError):
            if os.stat(folder / LOCK).st_ino == os.fstat(fd).st_ino:
                os.unlink(folder / LOCK)
    except OSError:
        pass
    finally:
        os.close(fd)


def _check_previous(folder: Path, overwrite: bool) -> None:
    previous = previous_run(folder)
    if previous is None:
        return
    if not overwrite:
        raise FolderTaken(
            f"{folder}: holds {previous}; set {OVERWRITE}=true to replace it, or run into another folder "
            "(hydra.run.dir=..., or hydra.sweep.dir=... for a sweep)"
        )
    here = Path.cwd().resolve()
    if folder.resolve() in (here, *here.parents):
        raise ValueError(f"{OVERWRITE}: will not clear {folder}: it holds the working directory {here}")


def _open_locked(folder: Path) -> tuple[int, bool]:
    """The lock file's descriptor, ``flock``-ed, and whether this call created the file. A file removed by the
    run that held it between our open and our lock is opened again (at most a few times)."""
    path = folder / LOCK
    for _ in range(10):
        try:
            fd, created = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666), True
        except FileExistsError:
            try:
                fd, created = os.open(path, os.O_RDWR), False
            except FileNotFoundError:
                continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _describe_holder(fd)
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            raise FolderTaken(f"{folder}: in use by a live {holder}; wait for it to end or run into another folder")
        try:
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                return fd, created
        except FileNotFoundError:
            pass
        os.close(fd)
    raise FolderTaken(f"{folder}: its lock file keeps changing; another run is starting there")


def _clear(folder: Path) -> None:
    """Remove everything in ``folder`` but its lock file."""
    for entry in folder.iterdir():
        if entry.name == LOCK:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _me() -> dict[str, object]:
    program = Path(sys.argv[0]).name if sys.argv else ""
    program = "python -m experiments.run" if program == "run.py" else program
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "since": time.strftime("%Y-%m-%d %H:%M:%S"),
        "command": " ".join([program, *sys.argv[1:]]),
    }


def _describe_holder(fd: int) -> str:
    try:
        entry = json.loads(os.pread(fd, 4096, 0) or b"{}")
        return f"run (pid {entry['pid']} on {entry['host']}, since {entry['since']}: {entry['command']})"
    except (OSError, ValueError, KeyError, TypeError):
        return "run (its lock file names no holder yet)"
