"""SIGINT, SIGTERM and SIGHUP end a run within seconds wherever they land, and mark it failed.

:func:`install` sets the handler first thing in the command (before Hydra, torch or numba are imported). Then:

* Before a run holds its folder (imports, composing the config) a signal ends the process at once, by that signal,
  with one line on stderr: there is nothing to mark.
* While a run holds its folder (:func:`begin`), the first signal marks the run failed there and then
  (``status.json``: ``Stopped: stopped by SIGTERM``), and raises :class:`Stopped` so that the run unwinds: its
  ``finally`` blocks end its workers, :mod:`experiments.run` reports the stop and the process dies by the signal.
  An exception raised in a handler can be lost: Python runs the handler at the next bytecode, which may be a
  callback that C code calls and whose exception C code ignores (numba's compiler calls back into Python this way
  while it compiles). So the handler also starts a watchdog thread: when such a callback swallows the stop
  (``sys.unraisablehook`` sees it) it delivers the stop again after :data:`REDELIVER_S`, and if the process is
  still alive :data:`GRACE_S` seconds after the signal it ends it: it ends the run's worker processes, releases the
  run folder, and exits with status ``128 + signal``.
* A second signal ends the process at once, the same way.
* Code that must not be cut (claiming the folder, recording completion) runs in :func:`deferred`: a signal then
  waits until the block ends.

Only the standard library at import: this module is loaded before anything heavy.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
import _thread
from collections.abc import Callable, Iterator
from typing import Any

from experiments.runs import claim, processes

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop a run."""
GRACE_S = 5.0
"""Seconds after the first signal within which the process ends, whatever it is doing."""
REDELIVER_S = 1.0
"""Seconds between deliveries of a stop that a C callback swallowed."""


class Stopped(BaseException):
    """The run was stopped by a signal; like ``KeyboardInterrupt``, not an ``Exception``, so that no ``except
    Exception`` holds it up."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum


class _State:
    def __init__(self) -> None:
        self.mark_failed: Callable[[str], None] | None = None  # set while a run holds its folder
        self.signum: int | None = None  # the first signal
        self.deferring = 0
        self.pending: int | None = None  # a signal that came during a deferred block
        self.acknowledged = False  # the stop reached the run's code
        self.swallowed = False  # a C callback ignored the stop
        self.redelivering = False
        self.cleaning = threading.Lock()


_state = _State()
_installed = False


def install() -> None:
    """Handle :data:`SIGNALS` in this process (from its main thread; elsewhere nothing changes). A signal this
    process was started ignoring stays ignored, as Python leaves it (``nohup``, a background job's SIGINT)."""
    global _installed
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in SIGNALS:
        if signal.getsignal(signum) != signal.SIG_IGN:
            signal.signal(signum, _handle)
    if not _installed:
        previous = sys.unraisablehook
        sys.unraisablehook = lambda unraisable: _unraisable(unraisable, previous)
        _installed = True


def begin(mark_failed: Callable[[str], None]) -> None:
    """A run now holds its folder: a signal calls ``mark_failed("Stopped: stopped by SIGxxx")`` and stops it."""
    _state.mark_failed = mark_failed
    _state.signum, _state.pending, _state.acknowledged, _state.swallowed = None, None, False, False


def finish() -> None:
    """The run is over (its status recorded): a signal ends the process at once again."""
    _state.mark_failed = None


def stopped() -> int | None:
    """The signal that stopped this run, if one did."""
    return _state.signum


def acknowledge() -> int | None:
    """Say that the stop reached the run's code (no delivery again); returns the signal, ``None`` if none came."""
    if _state.signum is not None:
        _state.acknowledged = True
    return _state.signum


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold a signal back until the block ends (then handle it as if it had just come)."""
    _state.deferring += 1
    try:
        yield
    finally:
        _state.deferring -= 1
        if not _state.deferring and _state.pending is not None:
            signum, _state.pending = _state.pending, None
            _handle(signum, None)


def die(signum: int, message: str | None = None) -> None:
    """Print ``message`` (one line, stderr), release this process's run folders and die by ``signum`` (from the main
    thread; elsewhere: exit with status ``128 + signum``)."""
    if message:
        with contextlib.suppress(Exception):
            sys.stderr.write(message + "\n")
            sys.stderr.flush()
    with contextlib.suppress(Exception):
        claim.release_all()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signum, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signum])
        os.kill(os.getpid(), signum)
        time.sleep(1.0)  # the signal is delivered at once; this is never reached
    os._exit(128 + signum)


def _handle(signum: int, frame: Any) -> None:
    state = _state
    if state.redelivering:
        state.redelivering = False
        raise Stopped(state.signum or signum)
    name = signal.Signals(signum).name
    if state.deferring:
        state.pending = state.pending or signum
        return
    if state.signum is not None:
        _end(signum, f"stopped by {name} (a second signal): ended at once")
    if state.mark_failed is None:
        die(signum, f"stopped by {name}")
    state.signum = signum
    _mark_failed(f"Stopped: stopped by {name}")
    threading.Thread(target=_watch, args=(signum,), name="stop-watchdog", daemon=True).start()
    raise Stopped(signum)


def _mark_failed(error: str) -> None:
    """Mark the run failed once (the handler, or the watchdog when the handler could not)."""
    if not _state.cleaning.acquire(timeout=1.0):
        return
    try:
        mark, _state.mark_failed = _state.mark_failed, None
        if mark is not None:
            mark(error)
    except Exception as exc:  # the stop goes on: a status that cannot be written must not keep the run alive
        with contextlib.suppress(Exception):
            sys.stderr.write(f"could not mark the run failed: {exc}\n")
    finally:
        _state.cleaning.release()


def _watch(signum: int) -> None:
    """Deliver a swallowed stop again; end the process :data:`GRACE_S` seconds after the signal."""
    deadline, last = time.monotonic() + GRACE_S, time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.05)
        if _state.swallowed and not _state.acknowledged and time.monotonic() - last >= REDELIVER_S:
            _state.swallowed, _state.redelivering, last = False, True, time.monotonic()
            _thread.interrupt_main(signum)
    name = signal.Signals(signum).name
    _end(signum, f"stopped by {name}: the run did not end within {GRACE_S:g} s of the signal; ended it")


def _end(signum: int, message: str) -> None:
    """End the process now: the run marked failed, its worker processes ended, its folder released."""
    _mark_failed(f"Stopped: stopped by {signal.Signals(signum).name}")
    with contextlib.suppress(Exception):
        processes.end_descendants(grace_s=0.5)
    die(signum, message)


def _unraisable(unraisable: Any, previous: Callable[[Any], None]) -> None:
    """Note a stop that C code ignored (it is delivered again); report anything else as Python would."""
    if isinstance(unraisable.exc_value, (Stopped, KeyboardInterrupt)) and _state.signum is not None:
        _state.swallowed = True
        return
    previous(unraisable)
