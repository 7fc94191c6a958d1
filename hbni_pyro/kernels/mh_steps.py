"""Pure update steps of the paper's Metropolis-Hastings sampler, vectorised over chains.

Every function takes the current state and data, draws from an explicit generator and
returns the new values and per-element acceptance indicators; nothing is mutated. Shapes:
any leading batch ``...`` (chains, or datasets x chains), ``N`` unlabelled outputs, ``M``
classes; data broadcast against the state (one dataset shared by every chain, or one each).

Labelled outputs never enter a step one by one: their per-class sufficient statistics
(``known_counts``, ``known_sums``) are computed once and added to those of the outputs whose
class the chain currently assigns. The class move runs over the unlabelled outputs in blocks
of :data:`CHUNK` rows, so its temporaries stay small however many outputs there are.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from hbni_pyro.density import class_log_lik, lifted_block_log_prob
from hbni_pyro.model import HyperPrior

CHUNK = 1 << 14
"""Unlabelled outputs per block of the class move."""


class MHState(NamedTuple):
    """Sampler state: ``c (..., N)`` long, ``log_theta (..., M)``, ``log_kappa (...)``, ``log_gamma (...)``."""

    c: Tensor
    log_theta: Tensor
    log_kappa: Tensor
    log_gamma: Tensor


class MHData(NamedTuple):
    """Fixed inputs: unlabelled log outputs, label mask, class prior, the class proposal weights and
    the labelled outputs' per-class statistics."""

    log_obs: Tensor  # (..., N, M) outputs whose class moves (rows with a label keep it)
    labels: Tensor  # (..., N) long, -1 where unknown
    log_prior: Tensor  # (M,)
    log_proposal: Tensor  # (..., N, M) log w_i: where a class move proposes to go
    proposal_cdf: Tensor  # (..., N, M) cumulative sums of w_i
    known_counts: Tensor | float = 0.0  # (..., M) labelled outputs per class (outside log_obs)
    known_sums: Tensor | float = 0.0  # (..., M, M) row c: sum of the log outputs labelled c


def class_log_lik_rows(log_theta: Tensor, log_obs: Tensor, beta: Tensor | None = None) -> Tensor:
    """``(..., N, M)`` log Dir(o_i; alpha_m) for every chain, output and class (``beta=None``: the paper's model)."""
    return class_log_lik(1.0, log_obs, log_theta.exp(), beta)


def update_classes(
    state: MHState, data: MHData, stay_prob: float, generator: torch.Generator, beta: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """One MH move for every unknown ``c_i`` in parallel (they are independent given theta).

    Proposal: ``q(c' | c) = stay_prob * 1[c' = c] + (1 - stay_prob) * w_{i c'}``, which keeps
    the current class with probability at least ``stay_prob``. For ``c' != c`` the Hastings
    ratio ``q(c | c') / q(c' | c) = w_{i c} / w_{i c'}`` corrects its asymmetry. ``beta`` gives
    the confusion-aware model's off-diagonal concentrations (``None``: the paper's model).

    Returns:
        new ``c (..., N)`` and ``accepted (..., N)`` bool (false where labelled or where it stayed).
    """
    c = state.c
    shape = c.shape
    dtype = data.log_prior.dtype
    move = torch.rand(shape, generator=generator, dtype=dtype) >= stay_prob
    u = torch.rand(shape, generator=generator, dtype=dtype)
    log_u = torch.rand(shape, generator=generator, dtype=dtype).log()
    new_c, accepted = torch.empty_like(c), torch.empty(shape, dtype=torch.bool)
    for start in range(0, shape[-1], CHUNK):
        rows = slice(start, start + CHUNK)
        cdf = data.proposal_cdf[..., rows, :]
        proposal = (u[..., rows].unsqueeze(-1) * cdf[..., -1:] > cdf).sum(-1).clamp_max(cdf.shape[-1] - 1)
        lik = class_log_lik_rows(state.log_theta, data.log_obs[..., rows, :], beta) + data.log_prior
        log_w = data.log_proposal[..., rows, :].expand(lik.shape)
        cur, new = c[..., rows].unsqueeze(-1), proposal.unsqueeze(-1)
        log_ratio = (lik.gather(-1, new) - lik.gather(-1, cur) + log_w.gather(-1, cur) - log_w.gather(-1, new)).squeeze(-1)
        ok = move[..., rows] & (log_u[..., rows] < log_ratio) & (data.labels[..., rows] < 0) & (proposal != c[..., rows])
        new_c[..., rows] = torch.where(ok, proposal, c[..., rows])
        accepted[..., rows] = ok
    return new_c, accepted


def sufficient_stats(c: Tensor, log_obs: Tensor, full: bool = False) -> tuple[Tensor, Tensor]:
    """Per chain and class: ``counts (..., M)`` of outputs assigned, and their log-output sums.

    Returns the sums of each class's own entry ``sum_{i: c_i = m} log o_{i m}`` ``(..., M)``, or
    with ``full=True`` the whole rows ``(..., M, M)`` (row ``m``: ``sum_{i: c_i = m} log o_i``).
    """
    num_classes = log_obs.shape[-1]
    batch = torch.broadcast_shapes(c.shape[:-1], log_obs.shape[:-2])
    counts = torch.zeros(batch + (num_classes,), dtype=log_obs.dtype)
    sums = torch.zeros(batch + ((num_classes, num_classes) if full else (num_classes,)), dtype=log_obs.dtype)
    for start in range(0, c.shape[-1], CHUNK):
        cc = c[..., start : start + CHUNK].expand(batch + (-1,))
        block = log_obs[..., start : start + CHUNK, :]
        counts.scatter_add_(-1, cc, torch.ones_like(cc, dtype=log_obs.dtype))
        if full:
            one_hot = torch.nn.functional.one_hot(cc, num_classes).to(log_obs.dtype)
            sums += one_hot.transpose(-1, -2) @ block
        else:
            sums.scatter_add_(-1, cc, block.expand(batch + block.shape[-2:]).gather(-1, cc.unsqueeze(-1)).squeeze(-1))
    return counts, sums


def theta_log_target(log_theta: Tensor, counts: Tensor, sum_log: Tensor, kappa: Tensor, gamma: Tensor) -> Tensor:
    """Unnormalised ``log p(log theta_m | c, o, kappa, gamma)`` per class ``(..., M)`` (Jacobian included).

    ``sum_log (..., M)`` holds each class's own-entry sums (see :func:`sufficient_stats`).
    """
    lik = lifted_block_log_prob(counts, sum_log, log_theta.exp(), log_theta.shape[-1])
    return lik + kappa.unsqueeze(-1) * log_theta - log_theta.exp() / gamma.unsqueeze(-1)


def update_theta(
    state: MHState, data: MHData, step: Tensor, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Gaussian random walk on every ``log theta_m`` in parallel (independent given c, kappa, gamma).

    Args:
        step: ``(..., M)`` proposal standard deviations on the log scale.

    Returns:
        new ``log_theta (..., M)`` and ``accepted (..., M)`` bool.
    """
    counts, sum_log = sufficient_stats(state.c, data.log_obs)
    counts = counts + data.known_counts
    known = data.known_sums
    sum_log = sum_log + (known.diagonal(dim1=-2, dim2=-1) if isinstance(known, Tensor) else known)
    kappa, gamma = state.log_kappa.exp(), state.log_gamma.exp()
    proposal = state.log_theta + step * torch.randn(step.shape, generator=generator, dtype=step.dtype)
    log_ratio = theta_log_target(proposal, counts, sum_log, kappa, gamma) - theta_log_target(
        state.log_theta, counts, sum_log, kappa, gamma
    )
    accepted = torch.rand(step.shape, generator=generator, dtype=step.dtype).log() < log_ratio
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
    eps = torch.randn(chol.shape[:-1], generator=generator, dtype=chol.dtype)
    delta = (chol @ eps.unsqueeze(-1)).squeeze(-1)
    new_k, new_g = state.log_kappa + delta[..., 0], state.log_gamma + delta[..., 1]
    log_ratio = hyper_log_target(new_k, new_g, state.log_theta, hp) - hyper_log_target(
        state.log_kappa, state.log_gamma, state.log_theta, hp
    )
    accepted = torch.rand(log_ratio.shape, generator=generator, dtype=chol.dtype).log() < log_ratio
    return torch.where(accepted, new_k, state.log_kappa), torch.where(accepted, new_g, state.log_gamma), accepted
