"""The sequence model's compiled per-sequence loops against their torch oracle, on one sampler state."""

import pytest
import torch

from hbni_pyro.density import ilr
from hbni_pyro.generative import sample_outputs
from hbni_pyro.kernels.sequence_mh import SequenceMetropolis
from hbni_pyro.kernels.sequence_steps import (
    GROUPED_LOOKS,
    between_data,
    class_log_probs,
    class_totals,
    draw_classes,
    draw_looks,
    look_factors,
    look_products,
    within_data,
)
from hbni_pyro.sequence_model import sequence_stats
from hbni_pyro.validation import as_outputs


def _frames(num_classes: int, lengths: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Outputs ``(N, M)`` of sequences of the given lengths, each class in turn, and their ids ``(N,)``."""
    g = torch.Generator().manual_seed(0)
    ids = torch.cat([torch.full((n,), k) for k, n in enumerate(lengths)])
    classes = torch.arange(len(lengths)) % num_classes
    theta = torch.linspace(2.0, 8.0, num_classes, dtype=torch.float64)
    return as_outputs(sample_outputs(theta, classes[ids], g)), ids


def _kernel(num_classes: int, lengths: list[int], datasets: int, rho: float = 0.0) -> SequenceMetropolis:
    """A sampler set up on ``datasets`` copies of unlabelled :func:`_frames`, their statistics whitened with the
    frame correlation ``rho``."""
    obs, ids = _frames(num_classes, lengths)
    stats = sequence_stats(obs, ids, torch.full_like(ids, -1), len(lengths), rho)
    kernel = SequenceMetropolis(num_chains=3 * datasets, seed=1)
    kernel.setup(5, type(stats)(*(t.expand((datasets,) + t.shape) for t in stats)))
    return kernel


@pytest.mark.parametrize("rho", [0.0, 0.6])
@pytest.mark.parametrize(
    "num_classes, lengths",
    [(4, [5, 9] * 30), (4, list(range(2, 12)) * 6)],
    ids=["grouped", "gathered"],  # 8 (class, weight) groups, then 40 > GROUPED_LOOKS: both torch paths
)
def test_compiled_loops_match_torch(num_classes, lengths, rho):
    assert (len(set(lengths)) * num_classes > GROUPED_LOOKS) == (len(set(lengths)) > 2)
    kernel = _kernel(num_classes, lengths, datasets=2, rho=rho)
    state, stats = kernel.state, kernel.stats
    c = draw_classes(state, stats, kernel.log_prior, torch.Generator().manual_seed(2))
    factors = look_factors(state, stats, c)
    z = torch.randn(c.shape + state.loc.shape[-1:], generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    looks = [look_products(factors, c, z, compiled=flag) for flag in (True, False)]
    torch.testing.assert_close(looks[0], looks[1], rtol=1e-10, atol=1e-10)
    moved = state._replace(c=c, look=looks[0])
    steps = (
        lambda flag: between_data(moved, compiled=flag),
        lambda flag: class_totals(c, moved.look, num_classes, compiled=flag),
        lambda flag: within_data(moved, stats, compiled=flag),
    )
    for step in steps:
        fast, oracle = step(True), step(False)
        for a, b in zip(fast, oracle, strict=True):
            assert a.shape == b.shape
            torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("rho", [0.0, 0.6])
def test_compiled_looks_follow_their_conditional(rho):
    """Whitened by their conditional's mean and Cholesky factor, 2 datasets x 3 chains x 600 compiled looks are
    standard normal: mean and variance of every coordinate within 5 standard errors."""
    kernel = _kernel(3, [4, 7] * 300, datasets=2, rho=rho)
    state, stats = kernel.state, kernel.stats
    c = draw_classes(state, stats, kernel.log_prior, torch.Generator().manual_seed(2))
    look = draw_looks(state, stats, c, torch.Generator().manual_seed(4), compiled=True)
    factors = look_factors(state, stats, c)
    mean = look_products(factors, c, torch.zeros_like(look), compiled=False)
    tril = factors.tril.gather(-3, factors.group[..., None, None].expand(c.shape + factors.tril.shape[-2:]))
    w = torch.linalg.solve_triangular(tril, (look - mean).unsqueeze(-1), upper=False).squeeze(-1).reshape(-1, 2)
    n = w.shape[0]
    assert (w.mean(0).abs() < 5 / n**0.5).all()
    assert ((w.var(0) - 1).abs() < 5 * (2 / n) ** 0.5).all()
    again = draw_looks(state, stats, c, torch.Generator().manual_seed(4), compiled=True)
    assert torch.equal(look, again)


def test_conditionals_under_correlated_frames_are_those_of_the_joint_gaussian():
    """With AR(1) frames (``rho = 0.6``), the kernel's whitened statistics give the closed-form conditionals of
    ``vec Y ~ N(1 (x) mu, R (x) W)``, ``R_st = rho^|s - t|``: the look's ``N(P^-1 (B^-1 m + W^-1 Y^T R^-1 1), P^-1)``
    with ``P = B^-1 + (1^T R^-1 1) W^-1``, the frames' scatter ``sum_k (Y_k - mu_k)^T R^-1 (Y_k - mu_k)`` about their
    looks, and the classes' log-odds from ``N(1 (x) m_c, R (x) W + 1 1^T (x) B_c)``."""
    rho, lengths = 0.6, [3, 5, 4, 1, 6]
    obs, ids = _frames(3, lengths)
    kernel = _kernel(3, lengths, datasets=1, rho=rho)
    state, stats = kernel.state, kernel.stats
    c = state.c
    factors = look_factors(state, stats, c)
    mean = look_products(factors, c, torch.zeros_like(state.look), compiled=False)
    cov = factors.cov.gather(-3, factors.group[..., None, None].expand(c.shape + factors.cov.shape[-2:]))
    logits = class_log_probs(stats, state, kernel.log_prior)
    compiled, oracle = within_data(state, stats, compiled=True), within_data(state, stats, compiled=False)
    chain = (0, 1)
    W, B, loc, mu = (t[chain].contiguous() for t in (state.within, state.between, state.loc, state.look))
    scatter = torch.zeros_like(W)
    for k, n in enumerate(lengths):
        y = ilr(obs[ids == k])
        lags = (torch.arange(n)[:, None] - torch.arange(n)[None, :]).abs().to(y.dtype)
        r_inv_one = torch.linalg.solve(rho**lags, torch.ones(n, dtype=y.dtype))
        m = int(c[chain][k])
        prec = torch.linalg.inv(B[m]) + r_inv_one.sum() * torch.linalg.inv(W)
        want = torch.linalg.solve(prec, torch.linalg.solve(B[m], loc[m]) + torch.linalg.solve(W, y.T @ r_inv_one))
        torch.testing.assert_close(cov[chain][k], torch.linalg.inv(prec), rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(mean[chain][k], want, rtol=1e-9, atol=1e-12)
        dev = y - mu[k]
        scatter += dev.T @ torch.linalg.solve(rho**lags, dev)
        joint = [
            torch.distributions.MultivariateNormal(
                loc[j].repeat(n), torch.kron(rho**lags, W) + torch.kron(torch.ones(n, n, dtype=y.dtype), B[j])
            ).log_prob(y.reshape(-1))
            for j in range(3)
        ]
        torch.testing.assert_close(
            logits[chain][k] - logits[chain][k][0], torch.stack(joint) - joint[0], rtol=0, atol=1e-9
        )
    for frames, got in (compiled, oracle):
        assert float(frames.expand(c.shape[:-1])[chain]) == sum(lengths)
        torch.testing.assert_close(got[chain], scatter, rtol=1e-9, atol=1e-10)
