"""The counter-based random streams of the compiled loops: distributions, keys, and the MH acceptance."""

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from hbni_infra.counter_random import _ZIG_F, _ZIG_R, _ZIG_X, accepts, next_u64, normal, unit, uniform
from hbni_infra.counter_random import stream_key as _stream_key


def stream_key(seed: int, controller: int, rollout: int) -> np.uint64:
    return np.uint64(_stream_key(np.uint64(seed), controller, rollout))


@njit(cache=False)
def _draws(key: np.uint64, n: int, kind: int) -> np.ndarray:
    rng = np.full(1, key, dtype=np.uint64)
    out = np.empty(n)
    for i in range(n):
        out[i] = uniform(rng) if kind == 0 else normal(rng)
    return out


@njit(cache=False)
def _accept_both_ways(key: np.uint64, log_ratios: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``accepts`` and the plain ``u < exp(x)`` test on two copies of one stream, per log ratio."""
    fast, plain = np.empty(log_ratios.shape[0], dtype=np.bool_), np.empty(log_ratios.shape[0], dtype=np.bool_)
    a, b = np.full(1, key, dtype=np.uint64), np.full(1, key, dtype=np.uint64)
    for i in range(log_ratios.shape[0]):
        x = log_ratios[i]
        fast[i] = accepts(a, x)
        plain[i] = True if x >= 0.0 else uniform(b) < math.exp(x)
    return fast, plain


def test_uniform_and_normal_follow_their_laws():
    u = _draws(stream_key(1, 2, 3), 200_000, 0)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-4
    z = _draws(stream_key(1, 2, 4), 200_000, 1)
    assert stats.kstest(z, "norm").pvalue > 1e-4
    assert abs(z.mean()) < 5 / math.sqrt(z.size)


@njit(cache=False)
def _normals_spelled_out(key: np.uint64, n: int) -> np.ndarray:
    """The ziggurat written plainly: layer from the low 8 bits, sign from bit 8, position ``unit(bits)`` times the
    layer's width, the sign applied last; the edge accepted under the density, the tail by Marsaglia's method."""
    rng = np.full(1, key, dtype=np.uint64)
    out = np.empty(n)
    for j in range(n):
        while True:
            bits = next_u64(rng)
            i = np.int64(bits & np.uint64(255))
            sign = -1.0 if (bits >> np.uint64(8)) & np.uint64(1) else 1.0
            x = unit(bits) * _ZIG_X[i]
            if x < _ZIG_X[i + 1]:
                out[j] = sign * x
                break
            if i == 0:
                while True:
                    tx = -math.log(1.0 - uniform(rng)) / _ZIG_R
                    ty = -math.log(1.0 - uniform(rng))
                    if 2.0 * ty > tx * tx:
                        break
                out[j] = sign * (_ZIG_R + tx)
                break
            if _ZIG_F[i] + uniform(rng) * (_ZIG_F[i + 1] - _ZIG_F[i]) < math.exp(-0.5 * x * x):
                out[j] = sign * x
                break
    return out


def test_normal_draws_the_signed_point_of_its_layer_exactly():
    key = stream_key(3, 1, 4)
    np.testing.assert_array_equal(_draws(key, 300_000, 1), _normals_spelled_out(key, 300_000))


def test_streams_depend_on_their_key_only():
    key = stream_key(9, 4, 5)
    np.testing.assert_array_equal(_draws(key, 100, 0), _draws(key, 100, 0))
    assert stream_key(9, 4, 6) != key and stream_key(9, 5, 5) != key
    assert stream_key(8, 4, 5) != key


def test_accepts_makes_the_same_decisions_as_the_exponential_test():
    """The bounds only skip the ``exp``: decisions and draws are those of ``u < exp(x)``, on log ratios from far
    below zero (where the upper bound rejects) to near zero (where the lower bound accepts) and above."""
    rng = np.random.default_rng(0)
    x = np.concatenate([-rng.exponential(10.0, 50_000), -rng.exponential(0.05, 50_000), rng.normal(0, 1, 10_000)])
    rng.shuffle(x)
    fast, plain = _accept_both_ways(stream_key(3, 0, 0), x)
    np.testing.assert_array_equal(fast, plain)


@pytest.mark.parametrize("log_ratio", [-5.0, -0.7, -0.01, 0.3])
def test_accepts_with_probability_min_one_exp(log_ratio):
    n = 100_000
    fast, _ = _accept_both_ways(stream_key(4, 1, 0), np.full(n, log_ratio))
    p = min(1.0, math.exp(log_ratio))
    assert abs(fast.mean() - p) <= 5 * math.sqrt(p * (1 - p) / n) + 1e-12
