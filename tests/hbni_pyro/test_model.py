"""The enumerated log marginal against brute force and against Pyro's own enumeration."""

import itertools

import pyro
import pytest
import torch
from pyro import poutine
from pyro.infer import TraceEnum_ELBO

from hbni_pyro import HyperPrior, gamma_log_prob, hbni_model, log_joint

HP = HyperPrior()


def _toy(num_obs=4, num_classes=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    obs = torch.distributions.Dirichlet(torch.ones(num_classes, dtype=torch.float64)).sample((num_obs,))
    theta = torch.rand(num_classes, generator=g, dtype=torch.float64) * 10 + 0.5
    return obs, theta, torch.tensor(1.7, dtype=torch.float64), torch.tensor(6.0, dtype=torch.float64)


def _brute_force(obs, theta, kappa, gamma, labels, prior):
    num_obs, num_classes = obs.shape
    base = gamma_log_prob(kappa, HP.beta, HP.eta) + gamma_log_prob(gamma, HP.nu, HP.omega)
    base = base + gamma_log_prob(theta, kappa, gamma).sum()
    terms = []
    for assignment in itertools.product(range(num_classes), repeat=num_obs):
        if any(y >= 0 and a != y for a, y in zip(assignment, labels.tolist())):
            continue
        lp = base.clone()
        for o, m in zip(obs, assignment):
            conc = torch.ones(num_classes, dtype=torch.float64)
            conc[m] += theta[m]
            lp = lp + prior[m].log() + torch.distributions.Dirichlet(conc).log_prob(o)
        terms.append(lp)
    return torch.logsumexp(torch.stack(terms), 0)


def _pyro_enumerated(obs, theta, kappa, gamma, labels, prior):
    conditioned = poutine.condition(hbni_model, data={"theta": theta, "kappa": kappa, "gamma": gamma})
    loss = TraceEnum_ELBO(max_plate_nesting=1).loss(conditioned, lambda *a, **k: None, obs, labels, prior, HP)
    return torch.tensor(-loss, dtype=torch.float64)


@pytest.mark.filterwarnings("ignore:TraceEnum_ELBO found no sample sites")
def test_log_marginal_matches_brute_force_unlabelled_and_partly_labelled():
    obs, theta, kappa, gamma = _toy()
    prior = torch.tensor([0.5, 0.3, 0.2], dtype=torch.float64)
    for labels in (torch.tensor([-1, -1, -1, -1]), torch.tensor([2, -1, 0, -1]), torch.tensor([0, 1, 2, 1])):
        ours = log_joint(obs, theta, kappa, gamma, labels=labels, class_prior=prior, hyperprior=HP)
        ref = _brute_force(obs, theta, kappa, gamma, labels, prior)
        torch.testing.assert_close(ours, ref, rtol=0, atol=1e-9)
        pyro.clear_param_store()
        torch.testing.assert_close(_pyro_enumerated(obs, theta, kappa, gamma, labels, prior), ref, rtol=0, atol=1e-9)


def test_log_joint_batches_over_chains():
    obs, theta, kappa, gamma = _toy()
    thetas = torch.stack([theta, theta * 2])
    kappas, gammas = torch.stack([kappa, kappa]), torch.stack([gamma, gamma / 2])
    batched = log_joint(obs, thetas, kappas, gammas)
    for i in range(2):
        torch.testing.assert_close(batched[i], log_joint(obs, thetas[i], kappas[i], gammas[i]))
