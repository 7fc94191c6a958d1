"""Update steps of the sequence-model sampler adapted to a new place, vectorised over chains.

Under a :class:`~hbni_pyro.models.sequence.shift_prior.ShiftPrior` the class means' prior mean is ``s a_c + b``; with a learnt
class mix the class prior is ``p ~ Dir(concentration)``. Each iteration adds three moves to the sequence model's
(:mod:`hbni_pyro.models.sequence.steps`):

- :func:`draw_shift`: the shared scale and offset given the class means, a Bayesian linear regression (exact);
- :func:`draw_prevalence`: the class mix given the sequences' classes, a Dirichlet (exact);
- :func:`relabel`: Metropolis swaps of two classes' parameters. Given the unlabelled sequences' classes relabelled
  with them, the swap leaves the likelihood of those sequences unchanged, so it is accepted by the prior and the
  labelled sequences alone: a chain that settled with two clusters exchanged (as an unlabelled fit can, early on)
  moves them back to the classes whose old looks they lie nearest, which Gibbs updates of one block at a time
  would take exponentially long to do.

Shapes: chains ``(..., )`` (datasets x chains per dataset), ``M`` classes, ``d = M - 1``, ``K`` sequences.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.sampling import gamma_variates
from hbni_pyro.models.sequence.program import SequenceStats
from hbni_pyro.models.sequence.shift_prior import ShiftPrior
from hbni_pyro.models.sequence.steps import SequenceState, gaussian_draw


def draw_shift(loc: Tensor, prior: ShiftPrior, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Exact draw of the shared scale ``s (...)`` and offset ``b (..., d)`` given the class means ``loc (..., M, d)``:
    ``loc_c = s anchor_c + b + N(0, shift_sd^2 I)`` with the priors of ``prior``."""
    a = prior.anchor.to(loc.device)
    M, d = a.shape
    like = dict(dtype=loc.dtype, device=loc.device)
    noise = 1.0 / prior.shift_sd**2
    prec = torch.zeros(d + 1, d + 1, **like)
    prec[0, 0] = 1.0 / prior.scale_sd**2 + noise * (a * a).sum()
    prec[0, 1:] = prec[1:, 0] = noise * a.sum(0)
    prec[1:, 1:] = torch.eye(d, **like) * (1.0 / prior.offset_sd**2 + noise * M)
    rhs = torch.cat(
        [(1.0 / prior.scale_sd**2 + noise * (a * loc).sum((-1, -2))).unsqueeze(-1), noise * loc.sum(-2)], -1
    )
    drawn = gaussian_draw(prec.expand(loc.shape[:-2] + (d + 1, d + 1)), rhs, generator)
    return drawn[..., 0], drawn[..., 1:]


def shifted_mean(prior: ShiftPrior, scale: Tensor, offset: Tensor) -> Tensor:
    """The class means' prior mean ``s anchor_c + b``, ``(..., M, d)``."""
    return scale[..., None, None] * prior.anchor.to(offset.device) + offset.unsqueeze(-2)


def draw_prevalence(c: Tensor, num_classes: int, concentration: float, generator: torch.Generator) -> Tensor:
    """Exact draw of the class mix ``p ~ Dir(concentration + counts)`` given every sequence's class ``c (..., K)``;
    returns ``log p`` as ``(..., 1, M)``, the shape :func:`~hbni_pyro.models.sequence.steps.draw_classes` reads."""
    counts = torch.zeros(c.shape[:-1] + (num_classes,), dtype=torch.float64, device=c.device)
    counts.scatter_add_(-1, c, torch.ones(c.shape, dtype=torch.float64, device=c.device))
    x = gamma_variates(concentration + counts, 1.0, generator)
    return (x / x.sum(-1, keepdim=True)).log().unsqueeze(-2)


def gaussian_log_prob(x: Tensor, loc: Tensor, cov: Tensor) -> Tensor:
    """``log N(x; loc, cov)`` for ``x``, ``loc (..., d)`` and ``cov (..., d, d)``, broadcasting."""
    tril = torch.linalg.cholesky(cov)
    z = torch.linalg.solve_triangular(tril, (x - loc).unsqueeze(-1), upper=False).squeeze(-1)
    d = x.shape[-1]
    half_logdet = tril.diagonal(dim1=-2, dim2=-1).log().sum(-1)
    return -0.5 * (z * z).sum(-1) - half_logdet - 0.5 * d * math.log(2 * math.pi)


def slot_scores(
    state: SequenceState, stats: SequenceStats, prior_mean: Tensor, shift_sd: float, log_prior: Tensor | None
) -> Tensor:
    """``(..., M, M)``: entry ``[a, b]`` is the log density of class ``a``'s parameters placed in class ``b``'s slot,
    in every term a swap changes: class ``b``'s mean prior ``N(prior_mean_b, shift_sd^2 I)`` at ``loc_a``, the
    looks of the sequences labelled ``b`` under ``N(loc_a, between_a)`` and, with a learnt class mix
    (``log_prior (..., 1, M)``), ``log p_a`` for each of them."""
    loc, M = state.loc, state.loc.shape[-2]
    scores = -0.5 * ((loc.unsqueeze(-2) - prior_mean.unsqueeze(-3)) ** 2).sum(-1) / shift_sd**2
    known = (stats.labels >= 0).reshape(-1, stats.labels.shape[-1]).any(0).nonzero().squeeze(-1)
    if known.numel():
        labels = stats.labels[..., known]  # (..., L): each dataset's labels of the sequences labelled in any
        looks = state.look[..., known, :].unsqueeze(-2)  # (..., L, 1, d)
        lik = gaussian_log_prob(looks, loc.unsqueeze(-3), state.between.unsqueeze(-4))  # (..., L, M: a)
        one_hot = torch.nn.functional.one_hot(labels.clamp_min(0), M).to(loc.dtype) * (labels >= 0).unsqueeze(-1)
        scores = scores + lik.transpose(-1, -2) @ one_hot  # (..., M: a, M: b)
        if log_prior is not None:
            scores = scores + log_prior.squeeze(-2).unsqueeze(-1) * one_hot.sum(-2).unsqueeze(-2)
    return scores


def relabel(
    state: SequenceState,
    stats: SequenceStats,
    prior_mean: Tensor,
    shift_sd: float,
    log_prior: Tensor | None,
    generator: torch.Generator,
) -> tuple[SequenceState, Tensor | None, Tensor]:
    """Metropolis swaps of every pair of classes in turn (a deterministic, self-inverse proposal): classes ``a`` and
    ``b`` exchange their means and spreads (and, when learnt, their share of the mix ``log_prior (..., 1, M)``), and
    the unlabelled sequences of one take the other's label; accepted with the ratio of :func:`slot_scores`.

    Returns the state, the class mix and the number of accepted swaps (a 0-d tensor)."""
    scores = slot_scores(state, stats, prior_mean, shift_sd, log_prior)
    M = scores.shape[-1]
    batch = scores.shape[:-2]
    held = torch.arange(M, device=scores.device).expand(batch + (M,)).clone()  # slot b holds class held[b]'s parameters
    accepted = torch.zeros((), dtype=torch.long, device=scores.device)
    for a in range(M):
        for b in range(a + 1, M):
            delta = scores[..., a, b] + scores[..., b, a] - scores[..., a, a] - scores[..., b, b]
            u = torch.rand(delta.shape, generator=generator, dtype=delta.dtype, device=delta.device)
            swap = u.log() < delta
            rows = torch.stack([scores[..., a, :], scores[..., b, :]], -2)
            scores[..., a, :] = torch.where(swap.unsqueeze(-1), rows[..., 1, :], rows[..., 0, :])
            scores[..., b, :] = torch.where(swap.unsqueeze(-1), rows[..., 0, :], rows[..., 1, :])
            pair = held[..., [a, b]]
            held[..., a] = torch.where(swap, pair[..., 1], pair[..., 0])
            held[..., b] = torch.where(swap, pair[..., 0], pair[..., 1])
            accepted = accepted + swap.sum()
    d = state.loc.shape[-1]
    loc = state.loc.gather(-2, held.unsqueeze(-1).expand(batch + (M, d)))
    between = state.between.gather(-3, held[..., None, None].expand(batch + (M, d, d)))
    unlabelled = (stats.labels < 0).expand(state.c.shape)
    c = torch.where(unlabelled, torch.argsort(held, -1).gather(-1, state.c), state.c)
    if log_prior is not None:
        log_prior = log_prior.squeeze(-2).gather(-1, held).unsqueeze(-2)
    return state._replace(c=c, loc=loc, between=between), log_prior, accepted
