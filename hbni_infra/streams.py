"""Independent random streams derived by name from one seed.

Every entry point takes one ``seed``; each of its stages and variants draws from its own stream,
``stream_seed(seed, "plan", "hbni")``: a :class:`numpy.random.SeedSequence` with entropy ``seed`` and
a spawn key made of a hash of each name. Streams of different names are independent, and adding a
stage never shifts the numbers of another, which adding constants to the seed does not guarantee
(one stage's offset 10 is another's offset 10).

This module is the only place that seeds a generator: :func:`torch_generator` and :func:`numpy_generator`
seed one with a seed as given (an entry point's own seed, or entropy words such as a seed and an index),
:func:`torch_stream` and :func:`numpy_stream` with a named stream of a seed. ``tests/hbni_infra/test_streams.py``
keeps it so.
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

from hbni_infra.checks import as_seed


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


def torch_generator(seed: int, device: str | torch.device = "cpu") -> torch.Generator | None:
    """A ``torch.Generator`` on ``device`` seeded with ``seed`` itself (an int in ``[0, 2**63)``); ``None`` on
    ``meta``, where tensors have shapes and no values and nothing is drawn."""
    seed = as_seed("seed", seed)
    device = torch.device(device)
    return None if device.type == "meta" else torch.Generator(device).manual_seed(seed)


def numpy_generator(*entropy: int) -> np.random.Generator:
    """A ``numpy.random.Generator`` on the entropy words given (ints in ``[0, 2**63)``, such as a seed and an index):
    ``numpy_generator(s)`` draws as ``numpy.random.default_rng(s)``, ``numpy_generator(s, i)`` as
    ``numpy.random.default_rng([s, i])``."""
    if not entropy:
        raise ValueError("entropy: expected at least one int, got none")
    words = [as_seed("entropy", word) for word in entropy]
    return np.random.default_rng(np.random.SeedSequence(words))
