"""Independent random streams derived by name from one seed.

Every entry point takes one ``seed``; each of its stages and variants draws from its own stream,
``stream_seed(seed, "plan", "hbni")``: a :class:`numpy.random.SeedSequence` with entropy ``seed`` and
a spawn key made of a hash of each name. Streams of different names are independent, and adding a
stage never shifts the numbers of another, which adding constants to the seed does not guarantee
(one stage's offset 10 is another's offset 10).
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch


def _key(name: str | int) -> int:
    if isinstance(name, bool) or not isinstance(name, (str, int)):
        raise TypeError(f"names: expected strings or ints, got {type(name).__name__} {name!r}")
    return int.from_bytes(hashlib.sha256(f"{type(name).__name__}:{name}".encode()).digest()[:4], "little")


def stream_seed(seed: int, *names: str | int) -> int:
    """A 62-bit seed of the stream ``names`` under ``seed`` (an int >= 0)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected an int >= 0, got {seed!r}")
    state = np.random.SeedSequence(int(seed), spawn_key=[_key(n) for n in names]).generate_state(1, np.uint64)
    return int(state[0] >> np.uint64(2))


def torch_stream(seed: int, *names: str | int) -> torch.Generator:
    """A ``torch.Generator`` seeded with :func:`stream_seed`."""
    return torch.Generator().manual_seed(stream_seed(seed, *names))


def numpy_stream(seed: int, *names: str | int) -> np.random.Generator:
    """A ``numpy.random.Generator`` seeded with :func:`stream_seed`."""
    return np.random.default_rng(stream_seed(seed, *names))
