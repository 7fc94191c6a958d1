"""Thread control: torch's intra-op threads (with NumPy's BLAS and OpenCV's threads), and the worker threads of
compiled loops.

The samplers, filters, SVM solver and simulators work on small tensors; on a shared or loaded
machine the hand-offs between torch's intra-op threads cost more than the parallelism saves.
Compiled loops (the rollout engine) split their work over :func:`worker_threads` threads; one
setting, :func:`threads`, sets both.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from types import ModuleType

import torch
from threadpoolctl import ThreadpoolController

from hbni_infra.checks import as_int

_workers: int | Callable[[], int] | None = None  # None: every core this process may run on
_pools: ThreadpoolController | None = None  # the thread pools of loaded native libraries, found once


def _blas_threads(threads: int | None) -> contextlib.AbstractContextManager:
    """NumPy's BLAS on ``threads`` threads inside the block (``None``: unchanged)."""
    global _pools
    if threads is None:
        return contextlib.nullcontext()
    if _pools is None:
        _pools = ThreadpoolController()
    return _pools.limit(limits=threads, user_api="blas")


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run torch on ``threads`` intra-op threads, and NumPy's BLAS and OpenCV on as many, inside the block
    (``None``: unchanged), then restore them (OpenCV's setting is the process's: on one thread, the renderer's
    frames cost less CPU time than on two, and are the same)."""
    _check(threads)
    cv2 = _opencv()
    before = torch.get_num_threads()
    before_cv = cv2.getNumThreads() if cv2 is not None else None
    if threads is not None:
        torch.set_num_threads(threads)
        if cv2 is not None:
            cv2.setNumThreads(threads)
    try:
        with _blas_threads(threads):
            yield
    finally:
        torch.set_num_threads(before)
        if cv2 is not None:
            cv2.setNumThreads(before_cv)


def _opencv() -> ModuleType | None:
    """OpenCV's module where one is installed (``classifiers`` needs it; ``hbni_pyro`` and ``decpomdp`` do not)."""
    try:
        import cv2
    except ImportError:
        return None
    return cv2


def single_thread() -> contextlib.AbstractContextManager[None]:
    """Run torch on one intra-op thread inside the block, then restore the previous count."""
    return torch_threads(1)


def _check(threads: int | None) -> None:
    if threads is not None:
        as_int("threads", threads, minimum=1)


def worker_threads() -> int:
    """Threads a compiled loop may use: the value set by :func:`threads` (asked now, when it set a function), else the
    cores available."""
    if callable(_workers):
        return as_int("threads()", _workers(), minimum=1)
    if _workers is not None:
        return _workers
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def set_threads(count: int) -> None:
    """Use ``count`` threads for torch's intra-op work, NumPy's BLAS, OpenCV and compiled loops from now on (a whole
    run's setting)."""
    global _workers
    _check(count)
    torch.set_num_threads(count)
    cv2 = _opencv()
    if cv2 is not None:
        cv2.setNumThreads(count)
    _blas_threads(count)  # a limit applies when made; it is never lifted
    _workers = count


@contextlib.contextmanager
def threads(count: int | Callable[[], int] | None) -> Iterator[None]:
    """Run torch's intra-op threads and compiled loops' worker threads on ``count`` threads inside the block
    (``None``: unchanged), then restore both. ``count`` may be a function of no arguments: each compiled loop then
    runs on as many threads as it returns when the loop starts (the cores that background work leaves, say), and
    torch on as many as it returns on entering the block."""
    global _workers
    now = count() if callable(count) else count
    _check(now)
    before = _workers
    with torch_threads(now):
        if count is not None:
            _workers = count
        try:
            yield
        finally:
            _workers = before
