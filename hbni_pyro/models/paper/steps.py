"""Pure update steps of the paper's Metropolis-Hastings sampler, vectorised over chains: the random walk on every
``log theta_m`` (the class move and the move of ``(kappa, gamma)`` are shared by the frame-level kernels:
:mod:`hbni_pyro.mcmc.class_moves`, :mod:`hbni_pyro.mcmc.hyper_move`).

Every function takes the current state and data, draws from an explicit generator (on the data's device, where
everything is computed) and returns the new values and acceptance indicators; nothing is mutated. Shapes: any
leading batch ``...`` (chains, or datasets x chains), ``M`` classes.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.density import lifted_block_log_prob
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
