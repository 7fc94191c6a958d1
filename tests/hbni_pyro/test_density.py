"""Closed-form densities against torch/pyro distributions, and the shape-scale Gamma convention."""

import pyro.distributions as dist
import pytest
import torch

from hbni_pyro.density import gamma_log_prob, lifted_dirichlet_log_prob
from hbni_pyro.model import HyperPrior


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

    from hbni_pyro.model import hbni_model

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
