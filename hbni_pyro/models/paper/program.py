"""The HBNI generative model as a Pyro program and in closed form (docs/architecture.md).

    kappa   ~ Ga(beta, eta)                 hyperprior, shape-scale
    gamma   ~ Ga(nu, omega)                 hyperprior, shape-scale
    theta_m ~ Ga(kappa, gamma)              m = 1..M, one noise level per class
    c_i     ~ Cat(p)                        true class of output i (known, unknown or masked)
    o_i     ~ Dir(theta_{c_i} e_{c_i} + 1)  the classifier output

Low ``theta_m`` means class m's outputs spread over the simplex (a noisy class); high
``theta_m`` means they sit near the vertex ``e_m`` (a reliable class).

Pyro's ``Gamma(concentration, rate)`` is shape-rate, so every shape-scale ``Ga(k, s)``
here is ``dist.Gamma(k, 1 / s)``; ``tests/hbni_pyro/test_model.py`` pins this.
"""

from __future__ import annotations

import pyro
import pyro.distributions as dist
import torch
from torch import Tensor

from hbni_pyro.distributions.density import (
    DirichletOutputs,
    concentrations,
    gamma_log_prob,
    lifted_dirichlet_log_prob,
)
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import gamma_variates
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_int
from hbni_infra.streams import torch_generator


def hbni_model(
    obs: Tensor,
    labels: Tensor | None = None,
    class_prior: Tensor | None = None,
    hyperprior: HyperPrior = HyperPrior(),
) -> None:
    """Pyro model of ``N`` outputs ``obs (N, M)`` with optional ``labels (N,)`` (-1 = unknown).

    Labelled outputs observe their class in the ``labelled`` plate; the rest have their class
    ``c`` marked for parallel enumeration in the ``unlabelled`` plate (``max_plate_nesting=1``).
    Inputs must already be validated (float64, strictly positive rows).
    """
    num_classes = obs.shape[1]
    p = class_prior if class_prior is not None else obs.new_full((num_classes,), 1.0 / num_classes)
    h = hyperprior
    kappa = pyro.sample("kappa", dist.Gamma(obs.new_tensor(h.beta), obs.new_tensor(1.0 / h.eta)))
    gamma = pyro.sample("gamma", dist.Gamma(obs.new_tensor(h.nu), obs.new_tensor(1.0 / h.omega)))
    with pyro.plate("classes", num_classes):
        theta = pyro.sample("theta", dist.Gamma(kappa, 1.0 / gamma))
    observe_outputs(obs, labels, p, concentrations(theta))


def observe_outputs(obs: Tensor, labels: Tensor | None, class_prior: Tensor, alpha: Tensor) -> None:
    """The output sites shared by the frame-level models: ``o_i ~ Dir(alpha[c_i])``, ``c_i ~ Cat(p)``.

    Labelled outputs observe their class in the ``labelled`` plate; the rest have ``c`` marked
    for parallel enumeration in the ``unlabelled`` plate (at dim -1).
    """
    known = torch.zeros(obs.shape[0], dtype=torch.bool) if labels is None else labels >= 0
    if known.any():
        with pyro.plate("labelled", int(known.sum()), dim=-1):
            c = pyro.sample("c_labelled", dist.Categorical(class_prior), obs=labels[known])
            pyro.sample("o_labelled", DirichletOutputs(alpha[c]), obs=obs[known])
    if (~known).any():
        with pyro.plate("unlabelled", int((~known).sum()), dim=-1):
            c = pyro.sample("c", dist.Categorical(class_prior), infer={"enumerate": "parallel"})
            pyro.sample("o", DirichletOutputs(alpha[c]), obs=obs[~known])


def log_joint(
    obs: Tensor,
    theta: Tensor,
    kappa: Tensor,
    gamma: Tensor,
    labels: Tensor | None = None,
    class_prior: Tensor | None = None,
    hyperprior: HyperPrior = HyperPrior(),
) -> Tensor:
    """``log p(obs, labels_known, theta, kappa, gamma)`` with unknown classes summed out, in closed form.

    Args:
        obs: ``(N, M)`` validated outputs.
        theta: ``(..., M)``; kappa, gamma: ``(...)`` — any batch shape (e.g. chains).
        labels: ``(N,)`` with -1 for unknown, or ``None`` (all unknown).

    Returns:
        ``(...)`` log joint density.
    """
    num_obs, num_classes = obs.shape
    p = class_prior if class_prior is not None else obs.new_full((num_classes,), 1.0 / num_classes)
    h = hyperprior
    lp = gamma_log_prob(kappa, h.beta, h.eta) + gamma_log_prob(gamma, h.nu, h.omega)
    lp = lp + gamma_log_prob(theta, kappa.unsqueeze(-1), gamma.unsqueeze(-1)).sum(-1)
    per_class = lifted_dirichlet_log_prob(obs, theta.unsqueeze(-2)) + p.log()
    if labels is None:
        labels = torch.full((num_obs,), -1, dtype=torch.long)
    known = labels >= 0
    marg = torch.logsumexp(per_class[..., ~known, :], -1).sum(-1)
    fixed = per_class[..., known, :].gather(-1, labels[known].expand(per_class.shape[:-2] + (-1,)).unsqueeze(-1))
    return lp + marg + fixed.squeeze(-1).sum(-1)


def prior_theta_log_density(theta: Tensor, hyperprior: HyperPrior, num_mc: int = 4000, seed: int = 0) -> Tensor:
    """Marginal prior density of one ``theta_m`` (kappa and gamma integrated out by Monte Carlo).

    Args:
        theta: points ``(K,)`` at which to evaluate.

    Returns:
        ``(K,)`` log density.
    """
    num_mc = as_int("num_mc", num_mc, minimum=1)
    g = torch_generator(seed)
    h = hyperprior
    kappa = gamma_variates(torch.full((num_mc,), h.beta), h.eta, g)
    gamma = gamma_variates(torch.full((num_mc,), h.nu), h.omega, g)
    lp = gamma_log_prob(theta.to(DTYPE).unsqueeze(-1), kappa, gamma)
    return torch.logsumexp(lp, -1) - torch.log(torch.tensor(float(num_mc), dtype=DTYPE))
