"""Pure update steps of the paper's Metropolis-Hastings sampler, vectorised over chains.

Every function takes the current state and data, draws from an explicit generator (on the
data's device, where everything is computed) and returns the new values and acceptance indicators. Nothing is mutated, except by
:func:`update_classes`, which rewrites the classes in place (see there). Shapes:
any leading batch ``...`` (chains, or datasets x chains), ``N`` unlabelled outputs, ``M``
classes; data broadcast against the state (one dataset shared by every chain, or one each).

Labelled outputs never enter a step one by one: their per-class sufficient statistics
(``known_counts``, ``known_sums``) are computed once and added to those of the outputs whose
class the chain currently assigns. The class move runs over the unlabelled outputs in blocks
of :data:`BLOCK_ELEMENTS` (chain, output) pairs, so its temporaries stay small however many
outputs and chains there are.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from hbni_pyro.density import concentrations, dirichlet_terms, lifted_block_log_prob, lifted_normaliser
from hbni_pyro.model import HyperPrior

BLOCK_ELEMENTS = 1 << 16
"""(chain, output) pairs per block of the class move and of the statistics: 512 KB per float64
temporary, so a block's data stay in cache across the chains and every temporary is the same
modest size from one block and one iteration to the next (the allocator reuses it)."""


def row_blocks(batch: tuple[int, ...], num_rows: int) -> list[slice]:
    """Slices of the ``num_rows`` outputs in blocks of about :data:`BLOCK_ELEMENTS` over the batch."""
    step = max(1, BLOCK_ELEMENTS // max(1, math.prod(batch)))
    return [slice(start, start + step) for start in range(0, num_rows, step)]


class MHState(NamedTuple):
    """Sampler state: ``c (..., N)`` long, ``log_theta (..., M)``, ``log_kappa (...)``, ``log_gamma (...)``."""

    c: Tensor
    log_theta: Tensor
    log_kappa: Tensor
    log_gamma: Tensor


class MHData(NamedTuple):
    """Fixed inputs: unlabelled log outputs, label mask, class prior, the class proposal (its log
    weights and alias tables, see :func:`frame_data`) and the labelled outputs' per-class statistics."""

    log_obs: Tensor  # (..., N, M) outputs whose class moves (rows with a label keep it)
    labels: Tensor  # (..., N) long, -1 where unknown
    log_prior: Tensor  # (M,)
    log_proposal: Tensor  # (..., N, M) log w_i: where a class move proposes to go
    alias_prob: Tensor  # (..., N, M) alias tables of w_i: keep column k with this probability ...
    alias: Tensor  # (..., N, M) long ... otherwise propose this class
    known_counts: Tensor | float = 0.0  # (..., M) labelled outputs per class (outside log_obs)
    known_sums: Tensor | float = 0.0  # (..., M, M) row c: sum of the log outputs labelled c


def alias_tables(weights: Tensor) -> tuple[Tensor, Tensor]:
    """Walker's alias tables of categorical distributions ``weights (..., M)`` (rows sum to 1).

    Vose's construction, vectorised over rows in ``M - 1`` rounds: each round settles, in every
    row, the unsettled column of least scaled weight ``q = M w`` (``q <= 1``), gives its leftover
    ``1 - q`` to the column of most (``>= 1``), and points its alias there. Drawing a uniform
    column ``k`` and keeping it with probability ``prob[k]``, else taking ``alias[k]``, draws
    from ``weights`` exactly (see :func:`alias_draw`).

    Returns:
        ``prob (..., M)`` in ``[0, 1]`` and ``alias (..., M)`` long.
    """
    num_classes = weights.shape[-1]
    q = weights * num_classes
    prob = torch.ones_like(q)
    alias = torch.arange(num_classes, device=q.device).expand(q.shape).clone()
    open_ = torch.ones(q.shape, dtype=torch.bool, device=q.device)
    for _ in range(num_classes - 1):
        small = q.masked_fill(~open_, torch.inf).argmin(-1, keepdim=True)
        large = q.masked_fill(~open_, -torch.inf).argmax(-1, keepdim=True)
        q_small = q.gather(-1, small)
        prob.scatter_(-1, small, q_small.clamp(0.0, 1.0))
        alias.scatter_(-1, small, large)
        q.scatter_add_(-1, large, q_small - 1)
        open_.scatter_(-1, small, False)
    return prob, alias


def take(table: Tensor, index: Tensor) -> Tensor:
    """``table[..., index]`` per element: ``table (..., M)`` broadcasting against ``index (...)`` long."""
    return table.expand(index.shape + table.shape[-1:]).gather(-1, index.unsqueeze(-1)).squeeze(-1)


def alias_draw(prob: Tensor, alias: Tensor, v: Tensor) -> Tensor:
    """Classes ``(...)`` drawn from alias tables ``prob, alias (..., M)`` (broadcasting against ``v``)
    with one uniform ``v (...)`` each: column ``k = floor(M v)``, kept if ``frac(M v) < prob[k]``."""
    num_classes = prob.shape[-1]
    x = v * num_classes
    k = x.long().clamp_max(num_classes - 1)
    return torch.where(x - k < take(prob, k), k, take(alias, k))


def frame_data(
    obs: Tensor, labels: Tensor, log_prior: Tensor, known_counts: Tensor | float = 0.0, known_sums: Tensor | float = 0.0
) -> MHData:
    """:class:`MHData` of outputs ``obs (..., N, M)``: the class move proposes from
    ``w_i = (o_i + 1/M) / 2``, a mixture of the output itself and the uniform distribution."""
    weights = 0.5 * obs + 0.5 / obs.shape[-1]
    return MHData(obs.log(), labels, log_prior, weights.log(), *alias_tables(weights), known_counts, known_sums)


def _class_terms(log_theta: Tensor, log_prior: Tensor, beta: Tensor | None) -> tuple[Tensor, Tensor]:
    """Per chain and class, the parameter terms of ``log p(c) + log Dir(o; alpha_c)``: an offset
    (``lgamma`` normaliser plus log prior) ``(..., M)`` and the weights of the log outputs, ``theta
    (..., M)`` on the own entry (the paper's model, ``beta=None``) or the exponents ``alpha - 1 (..., M, M)``."""
    theta = log_theta.exp()
    if beta is None:
        return lifted_normaliser(theta, theta.shape[-1]) + log_prior, theta
    normaliser, exponent = dirichlet_terms(concentrations(theta, beta))
    return normaliser + log_prior, exponent


def _log_lik_at(cls: Tensor, log_obs: Tensor, offset: Tensor, weight: Tensor) -> Tensor:
    """``log p(c_i = k) + log Dir(o_i; alpha_k)`` at ``k = cls_i``, ``(..., R)``, for log outputs
    ``log_obs (..., R, M)`` and :func:`_class_terms` ``(..., 1, M)`` / ``(..., 1, M, M)`` (broadcasting)."""
    if weight.dim() == offset.dim():
        return take(offset, cls) + take(weight, cls) * take(log_obs, cls)
    rows = weight.expand(cls.shape + weight.shape[-2:]).gather(
        -2, cls[..., None, None].expand(cls.shape + (1, weight.shape[-1]))
    )
    return take(offset, cls) + (rows.squeeze(-2) * log_obs).sum(-1)


def update_classes(
    state: MHState, data: MHData, stay_prob: float, generator: torch.Generator, beta: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """One MH move for every unknown ``c_i`` in parallel (they are independent given theta).

    Proposal: ``q(c' | c) = stay_prob * 1[c' = c] + (1 - stay_prob) * w_{i c'}``, which keeps
    the current class with probability at least ``stay_prob``. For ``c' != c`` the Hastings
    ratio ``q(c | c') / q(c' | c) = w_{i c} / w_{i c'}`` corrects its asymmetry. ``beta`` gives
    the confusion-aware model's off-diagonal concentrations (``None``: the paper's model).

    Only the current and proposed classes' terms are evaluated (``O(N)`` per chain, not ``O(N M)``),
    in blocks (:func:`row_blocks`). One uniform ``v`` decides both whether to move
    (``v >= stay_prob``) and, rescaled, where to (:func:`alias_draw`); a second one accepts.

    The classes are updated **in place**, block by block: a fresh ``(..., N)`` array every
    iteration, freed one iteration later, leaves a hole in the heap that the small tensors kept
    meanwhile (such as the MCMC driver's stored draws) split, so the next one no longer fits
    and the heap grows by one such array at a time over a long run.

    Returns:
        ``state.c``, updated, and the number of accepted moves (a 0-d long tensor; labelled
        outputs and proposals of the current class never count).
    """
    c = state.c
    dtype = data.log_prior.dtype
    offset, weight = _class_terms(state.log_theta, data.log_prior, beta)
    offset, weight = offset.unsqueeze(-2), weight.unsqueeze(-2 if beta is None else -3)
    accepted = torch.zeros((), dtype=torch.long, device=c.device)
    for rows in row_blocks(c.shape[:-1], c.shape[-1]):
        cur = c[..., rows]
        v = torch.rand(cur.shape, generator=generator, dtype=dtype, device=c.device)
        log_u = torch.rand(cur.shape, generator=generator, dtype=dtype, device=c.device).log()
        move = v >= stay_prob
        proposal = alias_draw(
            data.alias_prob[..., rows, :], data.alias[..., rows, :], (v - stay_prob).clamp_min(0) / (1 - stay_prob)
        )
        log_obs, log_w = data.log_obs[..., rows, :], data.log_proposal[..., rows, :]
        log_ratio = (
            _log_lik_at(proposal, log_obs, offset, weight)
            - _log_lik_at(cur, log_obs, offset, weight)
            + take(log_w, cur)
            - take(log_w, proposal)
        )
        ok = move & (log_u < log_ratio) & (data.labels[..., rows] < 0) & (proposal != cur)
        accepted += ok.sum()
        c[..., rows] = torch.where(ok, proposal, cur)
    return c, accepted


def sufficient_stats(c: Tensor, log_obs: Tensor, full: bool = False) -> tuple[Tensor, Tensor]:
    """Per chain and class: ``counts (..., M)`` of outputs assigned, and their log-output sums.

    Returns the sums of each class's own entry ``sum_{i: c_i = m} log o_{i m}`` ``(..., M)``, or
    with ``full=True`` the whole rows ``(..., M, M)`` (row ``m``: ``sum_{i: c_i = m} log o_i``).
    """
    num_classes = log_obs.shape[-1]
    batch = torch.broadcast_shapes(c.shape[:-1], log_obs.shape[:-2])
    like = dict(dtype=log_obs.dtype, device=log_obs.device)
    counts = torch.zeros(batch + (num_classes,), **like)
    sums = torch.zeros(batch + ((num_classes, num_classes) if full else (num_classes,)), **like)
    one = torch.ones((), **like)
    for rows in row_blocks(batch, c.shape[-1]):
        cc = c[..., rows].expand(batch + (-1,))
        block = log_obs[..., rows, :]
        counts.scatter_add_(-1, cc, one.expand(cc.shape))
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
