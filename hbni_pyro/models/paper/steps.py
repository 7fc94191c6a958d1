"""Pure update steps of the paper's Metropolis-Hastings sampler, vectorised over chains: the random walk on every
``log theta_m`` and the joint one on ``(log kappa, log gamma)`` (the class move is shared by the frame-level
kernels: :mod:`hbni_pyro.mcmc.class_moves`).

Every function takes the current state and data, draws from an explicit generator (on the data's device, where
everything is computed) and returns the new values and acceptance indicators; nothing is mutated. Shapes: any
leading batch ``...`` (chains, or datasets x chains), ``M`` classes.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.density import lifted_block_log_prob
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.mcmc.class_moves import MHData, MHState, sufficient_stats


def theta_log_target(log_theta: Tensor, counts: Tensor, sum_log: Tensor, kappa: Tensor, gamma: Tensor) -> Tensor:
    """Unnormalised ``log p(log theta_m | c, o, kappa, gamma)`` per class ``(..., M)`` (Jacobian included).

    ``sum_log (..., M)`` holds each class's own-entry sums (see :func:`sufficient_stats`).
    """
    lik = lifted_block_log_prob(counts, sum_log, log_theta.exp(), log_theta.shape[-1])
    return lik + kappa.unsqueeze(-1) * log_theta - log_theta.exp() / gamma.unsqueeze(-1)


def update_theta(
    state: MHState,
    data: MHData,
    step: Tensor,
    generator: torch.Generator,
    stats: tuple[Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """Gaussian random walk on every ``log theta_m`` in parallel (independent given c, kappa, gamma).

    Args:
        step: ``(..., M)`` proposal standard deviations on the log scale.
        stats: the unlabelled outputs' :func:`sufficient_stats` of ``state.c`` if already known.

    Returns:
        new ``log_theta (..., M)`` and ``accepted (..., M)`` bool.
    """
    counts, sum_log = sufficient_stats(state.c, data.log_obs) if stats is None else stats
    counts = counts + data.known_counts
    known = data.known_sums
    sum_log = sum_log + (known.diagonal(dim1=-2, dim2=-1) if isinstance(known, Tensor) else known)
    kappa, gamma = state.log_kappa.exp(), state.log_gamma.exp()
    like = dict(dtype=step.dtype, device=step.device)
    proposal = state.log_theta + step * torch.randn(step.shape, generator=generator, **like)
    log_ratio = theta_log_target(proposal, counts, sum_log, kappa, gamma) - theta_log_target(
        state.log_theta, counts, sum_log, kappa, gamma
    )
    accepted = torch.rand(step.shape, generator=generator, **like).log() < log_ratio
    return torch.where(accepted, proposal, state.log_theta), accepted


def hyper_log_target(log_kappa: Tensor, log_gamma: Tensor, log_theta: Tensor, hp: HyperPrior) -> Tensor:
    """Unnormalised ``log p(log kappa, log gamma | theta)`` per chain ``(...)`` (Jacobians included)."""
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
        chol: ``(..., 2, 2)`` lower Cholesky factor of each chain's proposal covariance.

    Returns:
        new ``log_kappa (...)``, ``log_gamma (...)`` and ``accepted (...)`` bool.
    """
    eps = torch.randn(chol.shape[:-1], generator=generator, dtype=chol.dtype, device=chol.device)
    delta = (chol @ eps.unsqueeze(-1)).squeeze(-1)
    new_k, new_g = state.log_kappa + delta[..., 0], state.log_gamma + delta[..., 1]
    log_ratio = hyper_log_target(new_k, new_g, state.log_theta, hp) - hyper_log_target(
        state.log_kappa, state.log_gamma, state.log_theta, hp
    )
    accepted = torch.rand(log_ratio.shape, generator=generator, dtype=chol.dtype, device=chol.device).log() < log_ratio
    return torch.where(accepted, new_k, state.log_kappa), torch.where(accepted, new_g, state.log_gamma), accepted
