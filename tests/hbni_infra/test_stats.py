"""The statistics module against scipy, closed forms and brute force, and its error paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from hbni_infra.stats import binomial_test, ks_test, monte_carlo_z, wilson_interval, z_test


@pytest.mark.parametrize(("k", "n", "p"), [(3, 10, 0.5), (28, 30, 0.99), (0, 5, 0.1), (450, 500, 0.95), (30, 30, 0.97)])
def test_binomial_test_is_scipys_and_sums_the_unlikelier_counts(k, n, p):
    assert binomial_test(k, n, p) == pytest.approx(stats.binomtest(k, n, p).pvalue, rel=1e-12)
    pmf = np.array([math.comb(n, j) * p**j * (1 - p) ** (n - j) for j in range(n + 1)])  # brute force
    assert binomial_test(k, n, p) == pytest.approx(min(1.0, pmf[pmf <= pmf[k] * (1 + 1e-7)].sum()), rel=1e-6)


def test_wilson_interval_closed_form():
    z = stats.norm.ppf(0.975)
    for k, n in [(8, 10), (0, 20), (20, 20), (10, 2000), (1, 3)]:
        p = k / n
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        lo, hi = wilson_interval(k, n)
        assert lo == pytest.approx(max(0.0, centre - half), abs=1e-12) and hi == pytest.approx(min(1.0, centre + half))
    assert wilson_interval(0, 20)[0] == 0.0 and wilson_interval(20, 20)[1] == 1.0
    assert wilson_interval(0, 2000)[1] == pytest.approx(z**2 / (2000 + z**2), rel=1e-12)  # k = 0: z^2 / (n + z^2)
    lo90, hi90 = wilson_interval(8, 10, confidence=0.9)
    lo95, hi95 = wilson_interval(8, 10)
    assert lo95 < lo90 < 0.8 < hi90 < hi95
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    for k, n in [(8, 10), (0, 20), (20, 20), (1, 3)]:  # zero standard errors: the proportion itself
        assert wilson_interval(k, n, confidence=0.0) == (k / n, k / n)


def test_ks_test_is_scipys_on_continuous_and_tied_samples():
    g = torch.Generator().manual_seed(0)
    for shift in (0.0, 0.2, 0.5):
        x, y = torch.randn(90, generator=g, dtype=torch.float64), torch.randn(1800, generator=g) + shift
        assert ks_test(x, y) == pytest.approx(stats.ks_2samp(x.numpy(), y.numpy()).pvalue, rel=1e-12)
    x, y = torch.randint(1, 4, (90,), generator=g), torch.randint(1, 5, (1800,), generator=g)  # ties: frame counts
    assert ks_test(x, y) == pytest.approx(stats.ks_2samp(x.numpy(), y.numpy()).pvalue, rel=1e-12)
    assert ks_test(x, x) == 1.0 and ks_test([1.0, 2.0, 3.0], np.array([1.0, 2.0, 3.0])) == 1.0
    assert math.isnan(ks_test(x[:0], y)) and math.isnan(ks_test(x, []))


def test_z_test_against_the_normal_law():
    x, y = np.array([1.0, 2.0, 3.0, 4.0]), np.array([2.0, 3.5, 5.0])
    se = math.sqrt(np.concatenate([x, y]).var(ddof=1) * (1 / 4 + 1 / 3))
    assert z_test(x, y) == pytest.approx(2 * stats.norm.sf(abs(x.mean() - y.mean()) / se), rel=1e-12)
    assert z_test(torch.tensor(x), torch.tensor(y)) == pytest.approx(z_test(x, y), rel=1e-12)
    assert z_test([1.0, 1.0], [1.0, 1.0]) == 1.0  # no spread and no gap
    assert math.isnan(z_test([1.0], [1.0, 2.0]))


def test_monte_carlo_z_is_the_gap_in_standard_errors_of_iid_draws():
    """With ess = draws (independent draws), the z of two summaries is the two-sample z statistic of their means."""
    g = np.random.default_rng(0)
    x, y = g.normal(0.3, 2.0, 400), g.normal(0.0, 1.0, 100)

    def summary(v: np.ndarray) -> dict:
        return {"theta": {"mean": v.mean(), "sd": v.std(ddof=1), "ess": float(len(v)), "r_hat": 1.0}}

    z = monte_carlo_z(summary(x), summary(y))
    se = math.sqrt(x.var(ddof=1) / len(x) + y.var(ddof=1) / len(y))
    assert z.keys() == {"theta"} and z["theta"] == pytest.approx((x.mean() - y.mean()) / se, rel=1e-12)
    assert monte_carlo_z(summary(y), summary(x))["theta"] == -z["theta"]  # signed: a's mean less b's


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: binomial_test(3, 2, 0.5), ValueError, "k: expected at most n=2"),
        (lambda: binomial_test(-1, 2, 0.5), ValueError, "k: expected an int >= 0"),
        (lambda: binomial_test(0, 0, 0.5), ValueError, "n: expected an int >= 1"),
        (lambda: binomial_test(1.5, 2, 0.5), TypeError, "k: expected an int"),
        (lambda: binomial_test(1, 2, 1.5), ValueError, "p: expected a finite number in"),
        (lambda: binomial_test(1, 2, float("nan")), ValueError, "p: "),
        (lambda: wilson_interval(1, 2, confidence=1.0), ValueError, "confidence: "),
        (lambda: wilson_interval(1, -2), ValueError, "n: expected an int >= 0"),
        (lambda: ks_test([[1.0]], [1.0]), ValueError, "x: expected a 1-d sample"),
        (lambda: ks_test([1.0], [float("nan")]), ValueError, "y: expected finite values"),
        (lambda: z_test([1.0, float("inf")], [1.0, 2.0]), ValueError, "x: expected finite values"),
        (lambda: monte_carlo_z({"a": {}, "c": {}}, {"b": {}}), ValueError, "b: expected every scalar of a, missing"),
    ],
)
def test_bad_arguments_are_refused(call, error, match):
    with pytest.raises(error, match=match):
        call()
