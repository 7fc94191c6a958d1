"""Pure update steps of the HBNI Metropolis-Hastings sampler, vectorised over chains.

Every function takes the current state and data, draws from an explicit generator and
returns the new values and per-element acceptance indicators; nothing is mutated.
Shapes: ``C`` chains, ``N`` outputs, ``M`` classes. The data may be shared by all chains
(``(1, N, M)``) or differ per chain (``(C, N, M)``, used to fit many datasets at once).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from hbni_pyro.model import HyperPrior


class MHState(NamedTuple):
    """Sampler state: ``c (C, N)`` long, ``log_theta (C, M)``, ``log_kappa (C,)``, ``log_gamma (C,)``."""

    c: Tensor
    log_theta: Tensor
    log_kappa: Tensor
    log_gamma: Tensor


class MHData(NamedTuple):
    """Fixed inputs: log outputs, label mask, class prior and the class proposal weights."""

    log_obs: Tensor  # (1 or C, N, M)
    labels: Tensor  # (1 or C, N) long, -1 where unknown
    log_prior: Tensor  # (M,)
    log_proposal: Tensor  # (1 or C, N, M) log w_i: where a class move proposes to go
    proposal_cdf: Tensor  # (1 or C, N, M) cumulative sums of w_i


def class_log_lik(log_theta: Tensor, log_obs: Tensor) -> Tensor:
    """``(C, N, M)`` log Dir(o_i; theta_m e_m + 1) for every chain, output and class."""
    theta = log_theta.exp().unsqueeze(-2)
    num_classes = log_obs.shape[-1]
    return torch.lgamma(num_classes + theta) - torch.lgamma(1 + theta) + theta * log_obs


def update_classes(state: MHState, data: MHData, stay_prob: float, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """One MH move for every unknown ``c_i`` in parallel (they are independent given theta).

    Proposal: ``q(c' | c) = stay_prob * 1[c' = c] + (1 - stay_prob) * w_{i c'}``, which keeps
    the current class with probability at least ``stay_prob``. For ``c' != c`` the Hastings
    ratio ``q(c | c') / q(c' | c) = w_{i c} / w_{i c'}`` corrects its asymmetry.

    Returns:
        new ``c (C, N)`` and ``accepted (C, N)`` bool (false where labelled or where it stayed).
    """
    c = state.c
    shape = c.shape
    move = torch.rand(shape, generator=generator, dtype=data.log_obs.dtype) >= stay_prob
    cdf = data.proposal_cdf
    u = torch.rand(shape, generator=generator, dtype=cdf.dtype).unsqueeze(-1) * cdf[..., -1:]
    proposal = (u > cdf).sum(-1).clamp_max(cdf.shape[-1] - 1)
    lik = class_log_lik(state.log_theta, data.log_obs) + data.log_prior
    log_w = data.log_proposal.expand(shape + (-1,))
    cur, new = c.unsqueeze(-1), proposal.unsqueeze(-1)
    log_ratio = (lik.gather(-1, new) - lik.gather(-1, cur) + log_w.gather(-1, cur) - log_w.gather(-1, new)).squeeze(-1)
    log_u = torch.rand(shape, generator=generator, dtype=cdf.dtype).log()
    accepted = move & (log_u < log_ratio) & (data.labels < 0) & (proposal != c)
    return torch.where(accepted, proposal, c), accepted


def sufficient_stats(c: Tensor, log_obs: Tensor) -> tuple[Tensor, Tensor]:
    """Per chain and class: ``counts (C, M)`` of outputs assigned, and ``sum log o_{i m}`` over them."""
    one_hot = torch.nn.functional.one_hot(c, log_obs.shape[-1]).to(log_obs.dtype)
    return one_hot.sum(-2), (one_hot * log_obs).sum(-2)


def theta_log_target(log_theta: Tensor, counts: Tensor, sum_log: Tensor, kappa: Tensor, gamma: Tensor) -> Tensor:
    """Unnormalised ``log p(log theta_m | c, o, kappa, gamma)`` per class ``(C, M)`` (Jacobian included)."""
    theta = log_theta.exp()
    num_classes = log_theta.shape[-1]
    lik = counts * (torch.lgamma(num_classes + theta) - torch.lgamma(1 + theta)) + theta * sum_log
    return lik + kappa.unsqueeze(-1) * log_theta - theta / gamma.unsqueeze(-1)


def update_theta(
    state: MHState, data: MHData, step: Tensor, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Gaussian random walk on every ``log theta_m`` in parallel (independent given c, kappa, gamma).

    Args:
        step: ``(C, M)`` proposal standard deviations on the log scale.

    Returns:
        new ``log_theta (C, M)`` and ``accepted (C, M)`` bool.
    """
    counts, sum_log = sufficient_stats(state.c, data.log_obs)
    kappa, gamma = state.log_kappa.exp(), state.log_gamma.exp()
    proposal = state.log_theta + step * torch.randn(step.shape, generator=generator, dtype=step.dtype)
    log_ratio = theta_log_target(proposal, counts, sum_log, kappa, gamma) - theta_log_target(
        state.log_theta, counts, sum_log, kappa, gamma
    )
    accepted = torch.rand(step.shape, generator=generator, dtype=step.dtype).log() < log_ratio
    return torch.where(accepted, proposal, state.log_theta), accepted


def hyper_log_target(log_kappa: Tensor, log_gamma: Tensor, log_theta: Tensor, hp: HyperPrior) -> Tensor:
    """Unnormalised ``log p(log kappa, log gamma | theta)`` per chain ``(C,)`` (Jacobians included)."""
    kappa, gamma = log_kappa.exp(), log_gamma.exp()
    num_classes = log_theta.shape[-1]
    theta_terms = kappa * log_theta.sum(-1) - log_theta.exp().sum(-1) / gamma
    theta_terms = theta_terms - num_classes * (torch.lgamma(kappa) + kappa * log_gamma)
    return theta_terms + hp.beta * log_kappa - kappa / hp.eta + hp.nu * log_gamma - gamma / hp.omega


def update_hyper(
    state: MHState, hp: HyperPrior, chol: Tensor, generator: torch.Generator
) -> tuple[Tensor, Tensor, Tensor]:
    """Joint Gaussian random walk on ``(log kappa, log gamma)``.

    Args:
        chol: ``(C, 2, 2)`` lower Cholesky factor of each chain's proposal covariance.

    Returns:
        new ``log_kappa (C,)``, ``log_gamma (C,)`` and ``accepted (C,)`` bool.
    """
    eps = torch.randn(chol.shape[:-1], generator=generator, dtype=chol.dtype)
    delta = (chol @ eps.unsqueeze(-1)).squeeze(-1)
    new_k, new_g = state.log_kappa + delta[..., 0], state.log_gamma + delta[..., 1]
    log_ratio = hyper_log_target(new_k, new_g, state.log_theta, hp) - hyper_log_target(
        state.log_kappa, state.log_gamma, state.log_theta, hp
    )
    accepted = torch.rand(log_ratio.shape, generator=generator, dtype=chol.dtype).log() < log_ratio
    return torch.where(accepted, new_k, state.log_kappa), torch.where(accepted, new_g, state.log_gamma), accepted
