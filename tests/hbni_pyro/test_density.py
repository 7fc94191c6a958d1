"""Closed-form densities against torch/pyro distributions, and the shape-scale Gamma convention."""

import pyro.distributions as dist
import pytest
import torch

from hbni_pyro.distributions import (
    DirichletOutputs,
    IlrNormalOutputs,
    assigned_log_lik,
    class_log_lik,
    concentrations,
    helmert_basis,
    ilr,
    ilr_log_jacobian,
)
from hbni_pyro import HyperPrior, gamma_log_prob, lifted_dirichlet_log_prob
from hbni_pyro.models.sequence.looks import look_basis, look_log_marginal, scatter_trace, within_log_prob
from hbni_pyro.models.sequence.wishart import (
    CholeskyFactorTransform,
    InvWishartCholesky,
    WishartCholesky,
    inv_wishart_log_prob,
    logdet_spd,
    sample_wishart,
    wishart_log_prob,
)


def test_lifted_dirichlet_matches_torch_dirichlet():
    g = torch.Generator().manual_seed(0)
    for num_classes in (2, 3, 7):
        obs = torch.distributions.Dirichlet(torch.ones(num_classes, dtype=torch.float64)).sample((50,))
        theta = torch.rand(num_classes, generator=g, dtype=torch.float64) * 50 + 0.01
        ours = lifted_dirichlet_log_prob(obs, theta)
        for m in range(num_classes):
            conc = torch.ones(num_classes, dtype=torch.float64)
            conc[m] += theta[m]
            ref = torch.distributions.Dirichlet(conc).log_prob(obs)
            torch.testing.assert_close(ours[:, m], ref, rtol=0, atol=1e-5)


def test_gamma_is_shape_scale_and_pyro_gamma_is_shape_rate():
    x = torch.linspace(0.1, 30, 40, dtype=torch.float64)
    shape, scale = 2.5, 4.0
    ours = gamma_log_prob(x, shape, scale)
    ref = dist.Gamma(torch.tensor(shape, dtype=torch.float64), torch.tensor(1 / scale, dtype=torch.float64)).log_prob(x)
    torch.testing.assert_close(ours, ref)
    # Mean of shape-scale Ga(k, s) is k * s; pyro's Gamma(k, rate) has mean k / rate.
    assert dist.Gamma(torch.tensor(shape), torch.tensor(1 / scale)).mean.item() == pytest.approx(shape * scale)


def test_model_gammas_are_shape_scale():
    """Every Gamma site of the Pyro model has the shape-scale mean k*s and variance k*s**2."""
    from pyro import poutine

    from hbni_pyro import hbni_model

    hp = HyperPrior(beta=3.0, eta=2.0, nu=4.0, omega=0.5)
    obs = torch.tensor([[0.7, 0.3], [0.2, 0.8]], dtype=torch.float64)
    tr = poutine.trace(hbni_model).get_trace(obs, torch.tensor([0, 1]), None, hp)
    kappa, gamma = tr.nodes["kappa"]["value"], tr.nodes["gamma"]["value"]
    for site, k, s in (("kappa", hp.beta, hp.eta), ("gamma", hp.nu, hp.omega), ("theta", kappa, gamma)):
        fn = tr.nodes[site]["fn"]
        torch.testing.assert_close(fn.mean, torch.as_tensor(k * s, dtype=torch.float64).expand_as(fn.mean))
        torch.testing.assert_close(fn.variance, torch.as_tensor(k * s * s, dtype=torch.float64).expand_as(fn.variance))


@pytest.mark.parametrize("field", ["beta", "eta", "nu", "omega"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), float("nan"), "2"])
def test_hyperprior_rejects_bad_values(field, bad):
    with pytest.raises(ValueError, match=f"HyperPrior.{field}"):
        HyperPrior(**{field: bad})


# -- the confusion-aware and sequence-aware likelihood terms ------------------------------------


def _simplex(n, m, seed):
    return torch.distributions.Dirichlet(torch.ones(m, dtype=torch.float64)).sample((n,))


def test_confusion_block_likelihood_matches_torch_dirichlet_and_reduces_to_the_paper():
    torch.manual_seed(0)
    M = 4
    obs = _simplex(30, M, 0)
    theta = torch.rand(M, dtype=torch.float64) * 20 + 0.1
    beta = torch.rand(M, M, dtype=torch.float64) * 3 + 0.05
    alpha = concentrations(theta, beta)
    assert torch.equal(alpha.diagonal(), theta + 1)
    ref = torch.stack([torch.distributions.Dirichlet(alpha[c]).log_prob(obs) for c in range(M)], -1)
    torch.testing.assert_close(class_log_lik(1.0, obs.log(), theta, beta), ref, rtol=0, atol=1e-9)
    # A block of 30 outputs from its count and summed log outputs.
    block = class_log_lik(torch.tensor([30.0]), obs.log().sum(0, keepdim=True), theta, beta)[0]
    torch.testing.assert_close(block, ref.sum(0), rtol=0, atol=1e-8)
    # beta = 1 is the paper's model, through the general and the lifted forms alike.
    ones = torch.ones(M, M, dtype=torch.float64)
    torch.testing.assert_close(
        class_log_lik(1.0, obs.log(), theta, ones), lifted_dirichlet_log_prob(obs, theta), rtol=0, atol=1e-9
    )
    # Per-class sufficient statistics: each class scores its own outputs.
    c = torch.arange(30) % M
    counts = torch.bincount(c, minlength=M).double()
    sums = torch.zeros(M, M, dtype=torch.float64).index_add_(0, c, obs.log())
    own = ref.gather(-1, c.unsqueeze(-1)).squeeze(-1)
    expected = torch.zeros(M, dtype=torch.float64).index_add_(0, c, own)
    torch.testing.assert_close(assigned_log_lik(counts, sums, theta, beta), expected, rtol=0, atol=1e-9)
    torch.testing.assert_close(
        assigned_log_lik(counts, sums, theta), assigned_log_lik(counts, sums, theta, ones), rtol=0, atol=1e-9
    )


def test_dirichlet_outputs_is_the_dirichlet():
    torch.manual_seed(1)
    alpha = torch.rand(5, 3, dtype=torch.float64) * 4 + 0.2
    obs = _simplex(5, 3, 1)
    torch.testing.assert_close(DirichletOutputs(alpha).log_prob(obs), dist.Dirichlet(alpha).log_prob(obs))
    assert DirichletOutputs(alpha).sample((7,)).shape == (7, 5, 3)


def test_ilr_is_an_isometry_and_its_jacobian_is_right():
    for M in (2, 3, 5):
        H = helmert_basis(M)
        torch.testing.assert_close(H @ H.T, torch.eye(M - 1, dtype=torch.float64))
        torch.testing.assert_close(H.sum(-1), torch.zeros(M - 1, dtype=torch.float64), rtol=0, atol=1e-12)
    o = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64)
    free = o[:2].clone()
    jac = torch.autograd.functional.jacobian(lambda x: ilr(torch.cat([x, 1 - x.sum(0, keepdim=True)])), free)
    torch.testing.assert_close(ilr_log_jacobian(o), torch.linalg.slogdet(jac)[1])


def test_ilr_normal_density_integrates_to_one():
    """Importance sampling from the uniform Dirichlet on the 2-simplex: E[p(o) / q(o)] = 1, with
    q = 2 (the uniform density); the tolerance is 5 Monte Carlo standard errors."""
    g = torch.Generator().manual_seed(3)
    n = 200_000
    e = -torch.rand(n, 3, generator=g, dtype=torch.float64).log()
    o = e / e.sum(-1, keepdim=True)
    d = IlrNormalOutputs(
        torch.tensor([0.3, -0.2], dtype=torch.float64), torch.tensor([[0.6, 0.0], [0.2, 0.5]], dtype=torch.float64)
    )
    w = d.log_prob(o).exp() / 2.0
    assert abs(float(w.mean()) - 1) < 5 * float(w.std()) / n**0.5


def test_look_marginal_and_within_term_give_the_joint_gaussian_of_a_sequence():
    """``n`` frames y_i = mu + e_i with mu ~ N(m, B), e_i ~ N(0, W) are jointly Gaussian with
    covariance I (x) W + 11^T (x) B; the two closed-form terms must add up to its log density."""
    torch.manual_seed(4)
    d, n = 3, 5
    a, b = torch.randn(d, d, dtype=torch.float64), torch.randn(d, d, dtype=torch.float64)
    B, W = a @ a.T + 0.1 * torch.eye(d, dtype=torch.float64), b @ b.T + 0.2 * torch.eye(d, dtype=torch.float64)
    m = torch.randn(d, dtype=torch.float64)
    y = torch.randn(n, d, dtype=torch.float64)
    cov = torch.kron(torch.eye(n, dtype=torch.float64), W) + torch.kron(torch.ones(n, n, dtype=torch.float64), B)
    ref = torch.distributions.MultivariateNormal(m.repeat(n), cov).log_prob(y.reshape(-1))
    basis, lam, logdet = look_basis(B, W)
    ybar = y.mean(0)
    scatter = (y - ybar).T @ (y - ybar)
    ours = look_log_marginal(float(n), basis @ (ybar - m), lam, logdet)
    ours = ours + within_log_prob(float(n), scatter_trace(torch.linalg.inv(W), scatter), logdet, d)
    torch.testing.assert_close(ours, ref, rtol=0, atol=1e-9)
    # The basis diagonalises B + W / k for every k.
    for k in (1.0, 7.0):
        torch.testing.assert_close(basis @ (B + W / k) @ basis.T, torch.diag(lam + 1 / k), rtol=0, atol=1e-10)


# -- Wishart densities and the Cholesky-factor distributions -----------------------------------


def _spd(d, seed):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(d, d, generator=g, dtype=torch.float64)
    return a @ a.T + 0.5 * torch.eye(d, dtype=torch.float64)


def test_wishart_densities_match_torch():
    V, X = _spd(3, 0), _spd(3, 1)
    df = torch.tensor(5.5, dtype=torch.float64)
    ref = torch.distributions.Wishart(df, covariance_matrix=V).log_prob(X)
    torch.testing.assert_close(wishart_log_prob(X, df, torch.linalg.inv(V), logdet_spd(V)), ref)
    # InvWishart(S; df, Psi): S^-1 ~ Wishart(df, Psi^-1), density over S = density over S^-1 * |S|^-(d+1).
    psi, S = _spd(3, 2), _spd(3, 3)
    ref = torch.distributions.Wishart(df, covariance_matrix=torch.linalg.inv(psi)).log_prob(
        torch.linalg.inv(S)
    ) - 4 * logdet_spd(S)
    torch.testing.assert_close(inv_wishart_log_prob(torch.linalg.inv(S), df, psi), ref)


def test_seeded_wishart_draws_have_the_right_mean_and_repeat():
    """Bartlett draws: mean df * V; every entry within 5 Monte Carlo standard errors."""
    V = _spd(3, 4)
    n = 40_000
    draws = sample_wishart(
        torch.full((n,), 6.0, dtype=torch.float64),
        torch.linalg.cholesky(V).expand(n, 3, 3),
        torch.Generator().manual_seed(5),
    )
    err = (draws.mean(0) - 6.0 * V).abs() / (draws.std(0) / n**0.5)
    assert err.max() < 5
    again = sample_wishart(
        torch.full((4,), 6.0, dtype=torch.float64),
        torch.linalg.cholesky(V).expand(4, 3, 3),
        torch.Generator().manual_seed(5),
    )
    assert torch.equal(
        again,
        sample_wishart(
            torch.full((4,), 6.0, dtype=torch.float64),
            torch.linalg.cholesky(V).expand(4, 3, 3),
            torch.Generator().manual_seed(5),
        ),
    )


def _vech_jacobian_logdet(fn, tril):
    d = tril.shape[-1]
    rows, cols = torch.tril_indices(d, d)

    def f(v):
        L = torch.zeros(d, d, dtype=v.dtype)
        L[rows, cols] = v
        return fn(L)[rows, cols]

    return torch.linalg.slogdet(torch.autograd.functional.jacobian(f, tril[rows, cols]))[1]


def test_cholesky_factor_distributions_carry_the_jacobian_of_l_to_l_lt():
    V = _spd(3, 6)
    L = torch.linalg.cholesky(_spd(3, 7))
    jac = _vech_jacobian_logdet(lambda x: x @ x.T, L)
    df = torch.tensor(6.0, dtype=torch.float64)
    S = L @ L.T
    torch.testing.assert_close(
        WishartCholesky(df, V).log_prob(L), wishart_log_prob(S, df, torch.linalg.inv(V), logdet_spd(V)) + jac
    )
    torch.testing.assert_close(
        InvWishartCholesky(df, V).log_prob(L), inv_wishart_log_prob(torch.linalg.inv(S), df, V) + jac
    )
    t = CholeskyFactorTransform()
    x = torch.randn(6, dtype=torch.float64)
    y = t(x)
    torch.testing.assert_close(t.inv(y), x)
    rows, cols = torch.tril_indices(3, 3)
    ref = torch.linalg.slogdet(torch.autograd.functional.jacobian(lambda v: t(v)[rows, cols], x))[1]
    torch.testing.assert_close(t.log_abs_det_jacobian(x, y), ref)
    assert t.forward_shape((4, 6)) == (4, 3, 3) and t.inverse_shape((4, 3, 3)) == (4, 6)
