"""The statistical tests and intervals of the honesty checks, from scipy where scipy has them.

* :func:`binomial_test`: two-sided exact binomial test (``scipy.stats.binomtest``).
* :func:`wilson_interval`: Wilson score interval of a proportion (``scipy.stats.binomtest(...).proportion_ci``).
* :func:`ks_test`: two-sided two-sample Kolmogorov-Smirnov test (``scipy.stats.ks_2samp``).
* :func:`z_test`: two-sided test of equal means by the normal approximation (scipy has no two-sample z test).
* :func:`monte_carlo_z`: the gap between two posterior summaries' means in Monte Carlo standard errors.

Samples are 1-d torch tensors, numpy arrays or sequences; an empty sample gives NaN, not an error, so that a
report can hold a row for a class that saw no streams. ``scipy.stats`` is imported on a test's first call: it takes
longer to import than the rest of ``hbni_pyro``, which a robot loads without ever running a test.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from hbni_infra.checks import as_float, as_int, as_probability

__all__ = ["binomial_test", "ks_test", "monte_carlo_z", "wilson_interval", "z_test"]


def _sample(name: str, x: Any) -> np.ndarray:
    values = np.asarray(x.detach().cpu().numpy() if hasattr(x, "detach") else x, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"{name}: expected a 1-d sample, got shape {values.shape}")
    if not np.isfinite(values).all():
        raise ValueError(f"{name}: expected finite values, got NaN or infinity")
    return values


def _count(k: Any, n: Any) -> tuple[int, int]:
    n = as_int("n", n, 0)
    k = as_int("k", k, 0)
    if k > n:
        raise ValueError(f"k: expected at most n={n} successes, got {k}")
    return k, n


def binomial_test(k: int, n: int, p: float) -> float:
    """Two-sided exact binomial test of ``k`` successes in ``n >= 1`` trials at rate ``p`` in ``[0, 1]``: the
    probability of every count no likelier than ``k``."""
    k, n = _count(k, n)
    as_int("n", n, 1)
    from scipy import stats

    return float(stats.binomtest(k, n, as_probability("p", p)).pvalue)


def wilson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval (no continuity correction) of the proportion ``k / n``; ``(nan, nan)`` when ``n = 0``;
    at ``confidence = 0`` (zero standard errors) the point ``k / n`` itself."""
    k, n = _count(k, n)
    confidence = as_float("confidence", confidence, 0.0, 1.0, high_open=True)
    if n == 0:
        return math.nan, math.nan
    from scipy import stats

    ci = stats.binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def ks_test(x: Any, y: Any) -> float:
    """Two-sided two-sample Kolmogorov-Smirnov p-value of ``x`` and ``y`` (scipy's exact law for small samples,
    its asymptotic one for large; conservative on discrete data); NaN when a sample is empty."""
    x, y = _sample("x", x), _sample("y", y)
    if not len(x) or not len(y):
        return math.nan
    from scipy import stats

    return float(stats.ks_2samp(x, y).pvalue)


def z_test(x: Any, y: Any) -> float:
    """Two-sided p-value of equal means of ``x`` and ``y`` (normal approximation, the variance of both samples
    pooled); NaN when a sample has fewer than 2 values."""
    x, y = _sample("x", x), _sample("y", y)
    if len(x) < 2 or len(y) < 2:
        return math.nan
    se = math.sqrt(np.concatenate([x, y]).var(ddof=1) * (1 / len(x) + 1 / len(y)))
    gap = abs(x.mean() - y.mean())
    if se == 0:
        return 1.0 if gap == 0 else 0.0
    return math.erfc(gap / se / math.sqrt(2))


def monte_carlo_z(a: Mapping[str, Mapping[str, float]], b: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Per scalar of posterior summary ``a`` (``name -> {"mean", "sd", "ess", ...}``, as ``HBNIPosterior.summary``
    gives), ``(mean_a - mean_b) / sqrt(sd_a**2 / ess_a + sd_b**2 / ess_b)``: the signed gap between the two
    samplers' means in Monte Carlo standard errors, each side's from its effective sample size.

    Raises:
        ValueError: ``b`` lacks a scalar of ``a``.
    """
    missing = sorted(set(a) - set(b))
    if missing:
        raise ValueError(f"b: expected every scalar of a, missing {missing}")
    return {
        k: (a[k]["mean"] - b[k]["mean"]) / math.sqrt(a[k]["sd"] ** 2 / a[k]["ess"] + b[k]["sd"] ** 2 / b[k]["ess"])
        for k in a
    }
