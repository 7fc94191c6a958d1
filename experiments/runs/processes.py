"""A process's tree on Linux (``/proc``): its live children and descendants, and ending them.

Only the standard library: a run's signal handling imports it before anything else (:mod:`experiments.runs.signals`).
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path


def start_time(pid: int) -> str | None:
    """The start time of process ``pid`` (``/proc/<pid>/stat``), ``None`` when it is gone or a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()
    return None if fields[0] in ("Z", "X") else fields[19]


def children(pid: int) -> list[int]:
    """The live child processes of ``pid``."""
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:  # gone (also while it is being listed)
        return []
    out: list[int] = []
    for task in tasks:
        try:
            out += [int(c) for c in Path(f"/proc/{pid}/task/{task}/children").read_text().split()]
        except OSError:
            pass
    return [c for c in dict.fromkeys(out) if start_time(c) is not None]


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid``."""
    out: list[int] = []
    todo = children(pid)
    while todo:
        child = todo.pop()
        if child not in out:
            out.append(child)
            todo += children(child)
    return out


def kill(pid: int, started: str | None, signum: int) -> None:
    """Send ``signum`` to ``pid`` if it is still the process that started at ``started`` (never to a reused pid)."""
    if started is None or start_time(pid) != started:
        return
    try:
        os.kill(pid, signum)
    except (ProcessLookupError, PermissionError):
        pass


def end_descendants(grace_s: float = 1.0) -> int:
    """SIGTERM every live process below this one, then SIGKILL those still alive after ``grace_s`` seconds (and any
    started meanwhile). Returns how many there were."""
    seen = {pid: start_time(pid) for pid in descendants(os.getpid())}
    for pid, started in seen.items():
        kill(pid, started, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(start_time(p) == t for p, t in seen.items() if t is not None):
        time.sleep(0.05)
    seen.update({pid: start_time(pid) for pid in descendants(os.getpid()) if pid not in seen})
    for pid, started in seen.items():
        kill(pid, started, signal.SIGKILL)
    return len(seen)
