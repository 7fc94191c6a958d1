"""The move on the hyperparameters that the frame-level kernels share: a joint Gaussian random walk on
``(log kappa, log gamma)`` given ``theta`` (``theta_m ~ Ga(kappa, gamma)``, both hyperparameters under shape-scale
Gamma priors), its proposal covariance learnt in warm-up (:class:`hbni_pyro.mcmc.base.AdaptiveWalk2D`).

Shapes: any leading batch ``...`` (chains, or datasets x chains), ``M`` classes.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.mcmc.class_moves import MHState


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
