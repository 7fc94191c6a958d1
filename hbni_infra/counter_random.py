"""Counter-based random numbers for compiled loops: one SplitMix64 stream per unit of work.

A stream is keyed by three integers, e.g. ``(seed, controller, rollout)`` in the rollout engine or
``(seed, iteration, chain and block)`` in the compiled MH class move: its key is a hash of the three, and
its ``i``-th draw is ``mix64(key + i * GOLDEN)`` (SplitMix64, Steele, Lea and Flood, OOPSLA 2014).
A draw therefore depends on nothing but the key and how many draws were made from it before, so a
seed gives the same results whatever the thread count, the chunking or the order of the work.

The state of a stream is one ``uint64`` (``rng[0]``, a length-1 array its owner keeps).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hbni_infra.numba_cache import use_cache_dir

use_cache_dir()  # before this module's cached function is decorated, and any that inline it

GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_CONTROLLER = np.uint64(0xD1B54A32D192ED03)
_ROLLOUT = np.uint64(0x8CB92BA72F3D8DD7)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@njit(inline="always")
def mix64(z: np.uint64) -> np.uint64:
    """SplitMix64's finaliser: a bijective 64-bit mix."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True)
def stream_key(seed: np.uint64, controller: np.int64, rollout: np.int64) -> np.uint64:
    """The key of rollout ``rollout`` of controller ``controller`` under ``seed``."""
    h = mix64(np.uint64(seed) + GOLDEN)
    h = mix64(h ^ (np.uint64(controller) * _CONTROLLER + GOLDEN))
    return mix64(h ^ (np.uint64(rollout) * _ROLLOUT + GOLDEN))


@njit(inline="always")
def next_u64(rng: np.ndarray) -> np.uint64:
    """The stream's next 64 random bits (advances ``rng[0]``)."""
    rng[0] += GOLDEN
    return mix64(rng[0])


@njit(inline="always")
def unit(bits: np.uint64) -> float:
    """The top 53 of 64 random bits as a uniform float64 in [0, 1) (converted as a signed integer, which is exact
    below 2**63 and one instruction, where an unsigned 64-bit conversion is a branchy sequence)."""
    return float(np.int64(bits >> _S11)) * (1.0 / 9007199254740992.0)


@njit(inline="always")
def uniform(rng: np.ndarray) -> float:
    """A uniform float64 in [0, 1): the stream's next draw (:func:`unit`)."""
    return unit(next_u64(rng))


def _ziggurat(layers: int = 256, r: float = 3.6541528853610088, v: float = 0.00492867323399) -> tuple:
    """Marsaglia and Tsang's (2000) ziggurat for the half-normal density ``f(x) = exp(-x^2 / 2)``:
    layer edges ``x[0] = v / f(r) > x[1] = r > ... > x[layers] = 0`` (each layer of area ``v``) and ``f(x)``."""
    x = np.zeros(layers + 1)
    x[0], x[1] = v / math.exp(-0.5 * r * r), r
    for i in range(2, layers):
        x[i] = math.sqrt(-2.0 * math.log(v / x[i - 1] + math.exp(-0.5 * x[i - 1] ** 2)))
    return x, np.exp(-0.5 * x * x), r


_ZIG_X, _ZIG_F, _ZIG_R = _ziggurat()
_LOW9 = np.uint64(511)
#: layer ``j & 255``'s width scaled by 2**-53, negative where bit 8 of ``j`` is set (see :func:`_signed_point`)
_ZIG_SIGNED_WIDTH = np.concatenate([_ZIG_X[:256], -_ZIG_X[:256]]) / 9007199254740992.0


@njit(inline="always")
def _signed_point(bits: np.uint64) -> tuple[np.int64, float]:
    """64 random bits as a ziggurat (layer, signed point): the low 8 bits pick the layer, bit 8 the sign (no
    branch: the bit is a coin flip) and the top 53 bits the position within the layer's width. One product of the
    position bits and ``_ZIG_SIGNED_WIDTH`` gives ``sign * unit(bits) * _ZIG_X[layer]`` exactly (the factors differ
    by powers of two), two multiplications fewer on the way to a draw."""
    layer_and_sign = np.int64(bits & _LOW9)
    return layer_and_sign & 255, float(np.int64(bits >> _S11)) * _ZIG_SIGNED_WIDTH[layer_and_sign]


@njit(inline="always")
def normal(rng: np.ndarray) -> float:
    """A standard normal float64 (ziggurat: one 64-bit draw in about 99 % of the calls).

    A point inside its layer's inner rectangle is returned at once; the rest (about 1 %) goes to
    :func:`_normal_edge`, compiled apart so that the inlined fast path stays small (an event loop runs faster). In a
    function compiled with numba's reference counting the call's mere presence costs several times the draw
    itself, so loops that draw many normals compile without it (``_nrt=False``), as the engine's chunk functions
    and the sequence model's look draws do.
    """
    i, y = _signed_point(next_u64(rng))
    if abs(y) < _ZIG_X[i + 1]:
        return y
    return _normal_edge(rng, i, math.copysign(1.0, y), abs(y))


@njit(inline="never", error_model="numpy")
def _normal_edge(rng: np.ndarray, i: np.int64, sign: float, x: float) -> float:
    """The ziggurat's rare path for a point ``x`` of layer ``i`` outside the inner rectangle: accepted under the
    density by a second uniform, the base layer's overhang being the tail ``x > r`` (Marsaglia's tail method);
    a rejected point draws again."""
    while True:
        if i == 0:  # the tail beyond r
            while True:
                tx = -math.log(1.0 - uniform(rng)) / _ZIG_R
                ty = -math.log(1.0 - uniform(rng))
                if 2.0 * ty > tx * tx:
                    return sign * (_ZIG_R + tx)
        if _ZIG_F[i] + uniform(rng) * (_ZIG_F[i + 1] - _ZIG_F[i]) < math.exp(-0.5 * x * x):
            return sign * x
        i, y = _signed_point(next_u64(rng))
        sign, x = math.copysign(1.0, y), abs(y)
        if x < _ZIG_X[i + 1]:
            return y


@njit(inline="always")
def accepts(rng: np.ndarray, log_ratio: float) -> bool:
    """A Metropolis-Hastings acceptance: ``True`` with probability ``min(1, exp(log_ratio))``.

    Draws one uniform ``u`` when ``log_ratio < 0`` and decides ``u < exp(log_ratio)`` exactly, but mostly
    without the exponential: ``1 + x <= exp(x) <= 1 / (1 - x)`` for ``x < 0`` settles all but the ``u`` between the
    two bounds (a rejection far below zero costs a division, not an ``exp``).
    """
    if log_ratio >= 0.0:
        return True
    u = uniform(rng)
    if u >= 1.0 / (1.0 - log_ratio):
        return False
    if u < 1.0 + log_ratio:
        return True
    return u < math.exp(log_ratio)


@njit(inline="always")
def below(rng: np.ndarray, n: np.int64) -> np.int64:
    """A uniform integer in [0, n) for a small ``n >= 1``."""
    k = np.int64(uniform(rng) * n)
    return k if k < n else n - 1


def draw_seed(generator) -> int:
    """A 62-bit seed for these streams drawn from a ``torch.Generator`` of any device (so a run seeded once stays
    reproducible); anything else (``None``, which would draw from torch's global stream) is a ``TypeError``."""
    import torch

    from hbni_infra.checks import as_generator

    generator = as_generator("generator", generator)
    return int(torch.randint(0, 2**62, (1,), generator=generator, device=generator.device))
