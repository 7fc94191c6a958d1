"""``summary()``'s effective sample size and quantiles, computed in memory linear in the draws: the same estimator
as pyro's (to rounding), close to ArviZ's, and right on AR(1) chains whose ESS has a closed form."""

from __future__ import annotations

import math

import pytest
import torch
from pyro.ops.stats import effective_sample_size as pyro_ess

from hbni_pyro import HBNIPosterior
from hbni_pyro.posterior import effective_sample_size, quantiles
from hbni_infra.streams import torch_stream


def ar1(chains: int, draws: int, rho: float, seed: int = 0) -> torch.Tensor:
    """``(chains, draws)`` stationary AR(1) series with lag-1 correlation ``rho`` and unit variance."""
    z = torch.randn(chains, draws, generator=torch_stream(seed, "ar1"), dtype=torch.float64)
    x = torch.empty_like(z)
    x[:, 0] = z[:, 0]
    scale = math.sqrt(1 - rho**2)
    for t in range(1, draws):
        x[:, t] = rho * x[:, t - 1] + scale * z[:, t]
    return x


@pytest.mark.parametrize(
    "chains, draws, rho",
    [(1, 50, 0.5), (4, 200, 0.9), (3, 101, -0.3), (2, 3, 0.0), (8, 500, 0.99), (16, 64, 0.2)],
)
def test_ess_is_pyros_estimator(chains, draws, rho):
    """The same formula as pyro's (Stan's, Geyer's initial monotone sequence), only its autocovariance comes from
    an FFT per block of chains and its running minimum from cummin: equal to float64 rounding (1e-10)."""
    x = ar1(chains, draws, rho) + torch.randn(chains, 1, generator=torch_stream(1, "offsets"), dtype=torch.float64)
    assert effective_sample_size(x) == pytest.approx(float(pyro_ess(x, 0, 1)), rel=1e-10)


def test_ess_of_constant_draws_is_nan_as_pyros():
    x = torch.ones(2, 10, dtype=torch.float64)
    assert math.isnan(effective_sample_size(x)) and math.isnan(float(pyro_ess(x, 0, 1)))


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_ess_is_close_to_arviz(rho):
    """ArviZ's ``ess(method="mean")`` estimates the same quantity from the same FFT autocovariances; it differs in
    the truncation (it stops at the first negative pair, pyro's clamps and runs the minimum to the end) and in
    normalising lag k by N rather than N - k. On 4 x 4000 weakly correlated draws these move the estimate by
    about 1 % (0.6 % at rho 0.5 and 0.03 % at 0 here); 5 % bounds it."""
    arviz = pytest.importorskip("arviz")
    x = ar1(4, 4000, rho, seed=2)
    assert effective_sample_size(x) == pytest.approx(float(arviz.ess(x.numpy(), method="mean")), rel=0.05)


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.8])
def test_ess_matches_the_ar1_closed_form(rho):
    """For AR(1) chains ESS = C N (1 - rho) / (1 + rho). The estimate's relative sd is about
    sqrt(2 (2 K + 1) / (C N)) for a truncation at lag K of a few correlation times (K ~ 20 at rho 0.8): below
    2.5 % at 8 x 20 000 draws, so 10 % is four of them."""
    chains, draws = 8, 20_000
    expected = chains * draws * (1 - rho) / (1 + rho)
    assert effective_sample_size(ar1(chains, draws, rho, seed=3)) == pytest.approx(expected, rel=0.1)


@pytest.mark.parametrize("probs", [(0.05, 0.95), (0.0, 1.0), (0.5,), (0.25, 0.333)])
def test_quantiles_are_torch_quantile(probs):
    """Selection (kthvalue) with torch.quantile's linear interpolation; no 16-million-entry limit."""
    x = torch.randn(1001, generator=torch_stream(4, "q"), dtype=torch.float64)
    expected = torch.quantile(x, torch.tensor(probs, dtype=torch.float64)).tolist()
    assert quantiles(x, probs) == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_summary_reports_the_linear_estimates():
    g = torch_stream(5, "posterior")
    theta = torch.rand(4, 300, 3, generator=g, dtype=torch.float64) + 1
    kappa, gamma = (
        torch.rand(4, 300, generator=g, dtype=torch.float64),
        torch.rand(4, 300, generator=g, dtype=torch.float64),
    )
    post = HBNIPosterior({"theta": theta, "kappa": kappa, "gamma": gamma}, torch.full((3,), 1 / 3, dtype=torch.float64))
    row = post.summary(prob=0.8)["theta[1]"]
    flat = theta[..., 1].reshape(-1)
    assert set(row) == {"mean", "sd", "q10", "q90", "ess", "r_hat"}
    assert row["ess"] == pytest.approx(float(pyro_ess(theta[..., 1], 0, 1)), rel=1e-10)
    assert row["q10"] == pytest.approx(float(torch.quantile(flat, 0.1)), rel=1e-12)
