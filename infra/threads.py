"""Thread control for small tensor programs.

The samplers, filters, SVM solver and simulators work on small tensors; on a shared or loaded
machine the hand-offs between torch's intra-op threads cost more than the parallelism saves.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run torch on ``threads`` intra-op threads inside the block (``None``: unchanged), then restore."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads: expected an int >= 1 or None, got {threads!r}")
    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def single_thread() -> contextlib.AbstractContextManager[None]:
    """Run torch on one intra-op thread inside the block, then restore the previous count."""
    return torch_threads(1)
