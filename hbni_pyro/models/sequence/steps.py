"""Pure update steps of the sequence-aware model's sampler, vectorised over chains.

The model (:mod:`hbni_pyro.models.sequence.program`) is conditionally conjugate, so every block but the
pooling is drawn from its exact conditional (an MH move whose proposal is the conditional,
accepted with probability 1); the pooling moves by a Gaussian random walk on its log with the
class spreads integrated out, after which they are drawn anew. Sequences enter only through
their statistics (:class:`~hbni_pyro.models.sequence.program.SequenceStats`).

Shapes: state ``(..., K)`` classes, ``(..., K, d)`` looks, ``(..., M, d)`` class means,
``(..., M, d, d)`` class spreads, ``(..., d, d)`` shared covariances; statistics broadcast
against the state's batch.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from hbni_pyro.distributions.density import normal_log_prob
from hbni_pyro.models.sequence import steps_numba as sequence_numba
from hbni_pyro.models.sequence.looks import look_basis, look_log_marginal
from hbni_pyro.models.sequence.program import SequenceStats, look_residuals
from hbni_pyro.models.sequence.wishart import logdet_spd, sample_wishart
from hbni_infra.counter_random import draw_seed

LOOK_CHUNK = 4096
"""Sequences per block when their looks are drawn by gathering each one's factors."""
GROUPED_LOOKS = 32
"""Up to this many (class, frame count) groups, every sequence's look is computed under every group's factors in
one batched product and the right one kept (no d x d factor gathered per sequence); beyond it, the factors are
gathered per sequence in blocks of LOOK_CHUNK."""


class SequenceState(NamedTuple):
    """``c (..., K)``, ``look (..., K, d)``, ``loc (..., M, d)``, ``between (..., M, d, d)``,
    ``between_mean (..., d, d)``, ``log_pooling (...)``, ``within (..., d, d)``."""

    c: Tensor
    look: Tensor
    loc: Tensor
    between: Tensor
    between_mean: Tensor
    log_pooling: Tensor
    within: Tensor


def gaussian_draw(prec: Tensor, rhs: Tensor, generator: torch.Generator) -> Tensor:
    """Draw from ``N(prec^-1 rhs, prec^-1)`` for batches of precisions ``(..., d, d)`` and ``rhs (..., d)``."""
    tril = torch.linalg.cholesky(prec)
    mean = torch.cholesky_solve(rhs.unsqueeze(-1), tril).squeeze(-1)
    z = torch.randn(mean.shape, generator=generator, dtype=mean.dtype, device=mean.device)
    return mean + torch.linalg.solve_triangular(tril.transpose(-1, -2), z.unsqueeze(-1), upper=True).squeeze(-1)


def draw_wishart_given(df: Tensor, scale_inv: Tensor, generator: torch.Generator) -> Tensor:
    """A ``Wishart(df, scale_inv^-1)`` draw: the conditional of a precision whose prior and data
    give the inverse scale ``scale_inv (..., d, d)``."""
    return sample_wishart(df, torch.linalg.cholesky(torch.linalg.inv(scale_inv)), generator)


def class_log_probs(stats: SequenceStats, state: SequenceState, log_prior: Tensor) -> Tensor:
    """``(..., K, M)`` unnormalised ``log p(c_k = m | frames, params)`` with the look integrated out
    (the frames' scatter term is the same for every class and drops out)."""
    basis, lam, logdet = look_basis(state.between, state.within.unsqueeze(-3))
    look = look_log_marginal(
        stats.count[..., None], look_residuals(basis, stats.mean_y, state.loc), lam.unsqueeze(-3), logdet.unsqueeze(-2)
    )
    return log_prior + look


def _per_sequence(table: Tensor, c: Tensor) -> Tensor:
    """Row ``c_k`` of a per-class ``table (..., M, *shape)`` for every sequence: ``(..., K, *shape)``."""
    index = c.reshape(c.shape + (1,) * (table.dim() - c.dim())).expand(c.shape + table.shape[c.dim() :])
    return table.gather(c.dim() - 1, index)


def draw_classes(
    state: SequenceState,
    stats: SequenceStats,
    log_prior: Tensor,
    generator: torch.Generator,
    compiled: bool | None = None,
) -> Tensor:
    """Exact draw of every unknown ``c_k`` from ``p(c_k | frames, params)`` (look integrated out);
    labelled sequences keep their label and cost nothing. ``compiled`` (default: on the CPU) draws the classes of
    a fit with unknown ones in a compiled loop (:func:`compiled_classes`), else by batched torch products."""
    labels = stats.labels.expand(state.c.shape)
    free = (stats.labels < 0).reshape(-1, stats.labels.shape[-1]).any(0).nonzero().squeeze(-1)
    if free.numel() and _compiled(compiled, state.loc):
        return compiled_classes(state, stats, log_prior, generator)
    u = torch.rand(state.c.shape + (1,), generator=generator, dtype=state.loc.dtype, device=state.loc.device)
    if not free.numel():
        return labels.clone()
    sub = SequenceStats(
        stats.count[..., free], stats.sum_y[..., free, :], stats.sum_yy[..., free, :, :], stats.labels[..., free]
    )
    cdf = torch.softmax(class_log_probs(sub, state, log_prior), -1).cumsum(-1)
    drawn = (u[..., free, :] * cdf[..., -1:] > cdf).sum(-1).clamp_max(cdf.shape[-1] - 1)
    c = labels.clone()
    c[..., free] = torch.where(labels[..., free] >= 0, labels[..., free], drawn)
    return c


def compiled_classes(
    state: SequenceState, stats: SequenceStats, log_prior: Tensor, generator: torch.Generator
) -> Tensor:
    """:func:`draw_classes` in a compiled loop over chains and sequences
    (:func:`hbni_pyro.models.sequence.steps_numba.classes`): each sequence's class weights from the look's basis, with the
    look variances computed once per distinct frame count; uniforms from counter-based streams seeded by
    ``generator``. The statistics are in the kernel's layout ``(D, 1, K, ...)``, the state ``(D, Cp, ...)``."""
    batch = state.c.shape[:-1]
    basis, lam, _ = look_basis(state.between, state.within.unsqueeze(-3))  # (..., M, d, d), (..., M, d)
    counts, which = torch.unique(stats.count, return_inverse=True)
    var = lam.unsqueeze(-2) + 1 / counts[:, None]  # (..., M, G, d)
    basis_loc = (basis @ state.loc.unsqueeze(-1)).squeeze(-1)
    M = state.loc.shape[-2]
    drawn = sequence_numba.classes(
        np.uint64(draw_seed(generator)),
        _chains_flat(basis, batch, 3),
        _chains_flat(basis_loc, batch, 2),
        _chains_flat(1 / var, batch, 3),
        _chains_flat(var.log().sum(-1), batch, 2),
        _chains_flat(log_prior.expand(batch + (1, M)).squeeze(-2), batch, 1),
        np.ascontiguousarray(stats.mean_y.squeeze(1).numpy()),
        np.ascontiguousarray(which.reshape(-1, which.shape[-1]).numpy()),
        np.ascontiguousarray(stats.labels.reshape(-1, stats.labels.shape[-1]).numpy()),
    )
    return torch.from_numpy(drawn).view(state.c.shape)


def _compiled(compiled: bool | None, t: Tensor) -> bool:
    """Whether to use the compiled loops of :mod:`hbni_pyro.models.sequence.steps_numba` (``None``: on the CPU)."""
    return t.device.type == "cpu" if compiled is None else compiled


def _chains_flat(t: Tensor, batch: torch.Size, trailing: int) -> np.ndarray:
    """``t (..., *trailing dims)`` broadcast to the chain batch and flattened to ``(B, *trailing dims)``, as numpy."""
    tail = t.shape[t.dim() - trailing :]
    return np.ascontiguousarray(t.expand(batch + tail).reshape((-1,) + tail).numpy())


class LookFactors(NamedTuple):
    """What every look's conditional needs: per (class, frame count) group ``g = c * U + u`` (``U`` distinct frame
    counts) the covariance ``cov (..., G, d, d)`` and its lower Cholesky factor ``tril``; per class
    ``pb_loc = B_c^-1 m_c (..., M, d)``; per sequence ``wy = W^-1 sum y (..., K, d)`` and its ``group (..., K)``."""

    cov: Tensor
    tril: Tensor
    pb_loc: Tensor
    wy: Tensor
    group: Tensor


def look_factors(state: SequenceState, stats: SequenceStats, c: Tensor) -> LookFactors:
    """The :class:`LookFactors` of the looks' conditional given the classes ``c (..., K)``: ``P = B_c^-1 + n W^-1``
    depends only on the class and the frame count, so it is factored once per group."""
    counts, which = torch.unique(stats.count, return_inverse=True)
    prec_between = torch.linalg.inv(state.between)  # (..., M, d, d)
    prec_within = torch.linalg.inv(state.within)  # (..., d, d)
    prec = prec_between.unsqueeze(-3) + counts[:, None, None] * prec_within[..., None, None, :, :]  # (..., M, U, d, d)
    cov = torch.linalg.inv(prec)
    return LookFactors(
        cov.flatten(-4, -3),
        torch.linalg.cholesky(cov).flatten(-4, -3),
        (prec_between @ state.loc.unsqueeze(-1)).squeeze(-1),
        stats.sum_y @ prec_within.transpose(-1, -2),
        c * counts.shape[0] + which.expand(c.shape),
    )


def look_products(f: LookFactors, c: Tensor, z: Tensor, compiled: bool | None = None) -> Tensor:
    """Every look ``cov_g (pb_loc_c + wy_k) + tril_g z_k`` for standard normals ``z (..., K, d)``.

    ``compiled`` (default: on the CPU) reads each sequence's own factors in a compiled loop
    (:func:`hbni_pyro.models.sequence.steps_numba.looks`). Otherwise, with at most :data:`GROUPED_LOOKS` groups every
    sequence goes through every group's factors in one batched product and keeps its own, else the factors are
    gathered per sequence in blocks of :data:`LOOK_CHUNK`."""
    if _compiled(compiled, z):
        batch = c.shape[:-1]
        drawn = sequence_numba.looks(
            *(_chains_flat(t, batch, 3) for t in (f.cov, f.tril)),
            *(_chains_flat(t, batch, 2) for t in (f.pb_loc, f.wy, z)),
            *(_chains_flat(t, batch, 1) for t in (c, f.group)),
        )
        return torch.from_numpy(drawn).view(z.shape)
    if f.cov.shape[-3] <= GROUPED_LOOKS:  # few groups: every sequence through every group's factors at once
        d = z.shape[-1]
        lhs = torch.cat([_per_sequence(f.pb_loc, c) + f.wy, z], -1)  # (..., K, 2d)
        factors = torch.cat([f.cov.transpose(-1, -2), f.tril.transpose(-1, -2)], -2)  # (..., G, 2d, d)
        factors = factors.movedim(-3, -2).flatten(-2)  # (..., 2d, G * d)
        drawn = (lhs @ factors).unflatten(-1, (-1, d))  # (..., K, G, d): mean + tril z under every group
        index = f.group[..., None, None].expand(f.group.shape + (1, d))
        return drawn.gather(-2, index).squeeze(-2)
    look = torch.empty(z.shape, dtype=z.dtype, device=z.device)
    for start in range(0, c.shape[-1], LOOK_CHUNK):
        rows = slice(start, start + LOOK_CHUNK)
        rhs = _per_sequence(f.pb_loc, c[..., rows]) + f.wy[..., rows, :]
        mean = (_per_sequence(f.cov, f.group[..., rows]) @ rhs.unsqueeze(-1)).squeeze(-1)
        look[..., rows, :] = mean + (_per_sequence(f.tril, f.group[..., rows]) @ z[..., rows, :].unsqueeze(-1)).squeeze(
            -1
        )
    return look


def draw_looks(
    state: SequenceState, stats: SequenceStats, c: Tensor, generator: torch.Generator, compiled: bool | None = None
) -> Tensor:
    """Exact draw of every look ``mu_k | c_k ~ N(P^-1 (B_c^-1 m_c + W^-1 sum y), P^-1)`` with
    ``P = B_c^-1 + n W^-1`` (:func:`look_factors`, :func:`look_products`). ``compiled`` (default: on the CPU): the
    standard normals come from counter-based streams seeded by ``generator``
    (:func:`hbni_pyro.models.sequence.steps_numba.normals`), else from ``torch.randn``."""
    factors = look_factors(state, stats, c)
    shape = c.shape + state.loc.shape[-1:]
    if _compiled(compiled, state.loc):
        z = torch.from_numpy(
            sequence_numba.normals(np.uint64(draw_seed(generator)), math.prod(shape[:-2]), *shape[-2:])
        )
        z = z.view(shape)
    else:
        z = torch.randn(shape, generator=generator, dtype=state.loc.dtype, device=state.loc.device)
    return look_products(factors, c, z, compiled)


def update_classes_and_looks(
    state: SequenceState, stats: SequenceStats, log_prior: Tensor, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Exact blocked draw of every ``(c_k, mu_k)``: :func:`draw_classes`, then :func:`draw_looks`."""
    c = draw_classes(state, stats, log_prior, generator)
    return c, draw_looks(state, stats, c, generator)


def class_totals(c: Tensor, values: Tensor, num_classes: int, compiled: bool | None = None) -> tuple[Tensor, Tensor]:
    """``counts (..., M)`` of sequences per class and ``sum_{k: c_k = m} values_k`` ``(..., M, *value shape)``: in a
    compiled loop (``compiled``, default: on the CPU; :func:`hbni_pyro.models.sequence.steps_numba.class_sums`) or by a
    one-hot product."""
    if _compiled(compiled, values):
        batch, tail = c.shape[:-1], values.shape[c.dim() :]
        flat = values.reshape(values.shape[: c.dim()] + (-1,))
        counts, sums = sequence_numba.class_sums(_chains_flat(flat, batch, 2), _chains_flat(c, batch, 1), num_classes)
        return torch.from_numpy(counts).view(batch + (num_classes,)), torch.from_numpy(sums).view(
            batch + (num_classes,) + tail
        )
    one_hot = torch.nn.functional.one_hot(c, num_classes).to(values.dtype)  # (..., K, M)
    flat = values.reshape(values.shape[: c.dim()] + (-1,))
    sums = one_hot.transpose(-1, -2) @ flat
    return one_hot.sum(-2), sums.reshape(sums.shape[:-1] + values.shape[c.dim() :])


def draw_locs(state: SequenceState, prior_mean: Tensor, prior_sd: float, generator: torch.Generator) -> Tensor:
    """Exact draw of the class means: ``N(prior_mean, prior_sd^2 I)`` prior, looks ``N(m_c, B_c)``."""
    num_classes, d = state.loc.shape[-2:]
    counts, look_sums = class_totals(state.c, state.look, num_classes)
    prec_between = torch.linalg.inv(state.between)
    prec = (
        torch.eye(d, dtype=state.loc.dtype, device=state.loc.device) / prior_sd**2
        + counts[..., None, None] * prec_between
    )
    rhs = prior_mean / prior_sd**2 + (prec_between @ look_sums.unsqueeze(-1)).squeeze(-1)
    return gaussian_draw(prec, rhs, generator)


def between_data(state: SequenceState, compiled: bool | None = None) -> tuple[Tensor, Tensor]:
    """Per class: the number of sequences and the scatter of their looks about the class mean, in a compiled
    loop (``compiled``, default: on the CPU; :func:`hbni_pyro.models.sequence.steps_numba.class_scatter`) or
    accumulated class by class (no per-sequence outer products)."""
    num_classes = state.loc.shape[-2]
    if _compiled(compiled, state.look):
        batch = state.c.shape[:-1]
        counts, scatter = sequence_numba.class_scatter(
            *(_chains_flat(t, batch, 2) for t in (state.look, state.loc)), _chains_flat(state.c, batch, 1)
        )
        return torch.from_numpy(counts).view(state.loc.shape[:-1]), torch.from_numpy(scatter).view(
            state.loc.shape + state.loc.shape[-1:]
        )
    one_hot = torch.nn.functional.one_hot(state.c, num_classes).to(state.look.dtype)  # (..., K, M)
    dev = state.look - _per_sequence(state.loc, state.c)
    scatter = torch.stack([(dev * one_hot[..., m : m + 1]).transpose(-1, -2) @ dev for m in range(num_classes)], -3)
    return one_hot.sum(-2), scatter


def within_data(state: SequenceState, stats: SequenceStats, compiled: bool | None = None) -> tuple[Tensor, Tensor]:
    """The number of frames ``(...)`` and their scatter about their sequence's look ``(..., d, d)``: in a compiled
    loop (``compiled``, default: on the CPU), each sequence's scatter about its mean plus
    ``n (ybar - mu)(ybar - mu)^T`` (:func:`hbni_pyro.models.sequence.steps_numba.offset_scatter`); else
    ``sum_k [sum_i y y^T - s mu^T - mu s^T + n mu mu^T]`` by matrix products over the sequences."""
    mu = state.look
    if _compiled(compiled, mu):
        batch = state.c.shape[:-1]
        offsets = sequence_numba.offset_scatter(
            _chains_flat(stats.mean_y, batch, 2), _chains_flat(mu, batch, 2), _chains_flat(stats.count, batch, 1)
        )
        scatter = stats.scatter.sum(-3) + torch.from_numpy(offsets).view(batch + mu.shape[-1:] * 2)
        return stats.count.sum(-1), scatter
    cross = stats.sum_y.transpose(-1, -2) @ mu  # sum_k s_k mu_k^T
    scatter = (
        stats.sum_yy.sum(-3) - cross - cross.transpose(-1, -2) + (mu * stats.count.unsqueeze(-1)).transpose(-1, -2) @ mu
    )
    return stats.count.sum(-1), scatter


def draw_within(
    state: SequenceState, stats: SequenceStats, df0: float, psi0: Tensor, generator: torch.Generator
) -> Tensor:
    """Exact draw of the frames' covariance ``W``: ``InvWishart(df0, psi0)`` prior, frames ``N(mu_k, W)``."""
    frames, scatter = within_data(state, stats)
    df = (df0 + frames).expand(state.log_pooling.shape)
    return torch.linalg.inv(draw_wishart_given(df, psi0 + scatter, generator))


def pooling_log_target(
    log_pool: Tensor, mean: Tensor, counts: Tensor, scatter: Tensor, median: float, sd: float
) -> Tensor:
    """Unnormalised ``log p(log pool | looks, class means, B)`` with every class spread integrated out.

    ``S_c ~ InvWishart(nu, pool * S)`` (``nu = pool + d + 1``) is conjugate to ``n_c`` Gaussian
    vectors with scatter ``R_c``, whose marginal is ``|pool S|^(nu/2) Gamma_d((nu + n_c)/2) /
    (Gamma_d(nu/2) |pool S + R_c|^((nu + n_c)/2))`` up to factors free of ``pool``. Moving ``pool``
    with the class covariances integrated out, then drawing them anew, mixes far better than moving
    it given them. ``N(log median, sd^2)`` prior on ``log pool``.
    """
    d = mean.shape[-1]
    pool = log_pool.exp()[..., None]
    nu = pool + d + 1
    psi = pool[..., None, None] * mean.unsqueeze(-3)
    terms = 0.5 * nu * logdet_spd(psi) - 0.5 * (nu + counts) * logdet_spd(psi + scatter)
    terms = terms + torch.mvlgamma(0.5 * (nu + counts), d) - torch.mvlgamma(0.5 * nu, d)
    return terms.sum(-1) + normal_log_prob(log_pool, math.log(median), sd)


def update_pooling(
    log_pool: Tensor,
    mean: Tensor,
    counts: Tensor,
    scatter: Tensor,
    median: float,
    sd: float,
    step: Tensor,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor]:
    """Gaussian random walk on ``log pool`` (class covariances integrated out); returns it and ``accepted``."""
    like = dict(dtype=log_pool.dtype, device=log_pool.device)
    proposal = log_pool + step * torch.randn(log_pool.shape, generator=generator, **like)
    args = (mean, counts, scatter, median, sd)
    ratio = pooling_log_target(proposal, *args) - pooling_log_target(log_pool, *args)
    ok = torch.rand(log_pool.shape, generator=generator, **like).log() < ratio
    return torch.where(ok, proposal, log_pool), ok


def draw_class_covs(
    log_pool: Tensor, mean: Tensor, counts: Tensor, scatter: Tensor, generator: torch.Generator
) -> Tensor:
    """Exact draw of the class covariances: ``InvWishart(pool + d + 1, pool S)`` prior, data ``(counts, scatter)``."""
    d = mean.shape[-1]
    pool = log_pool.exp()
    psi = pool[..., None, None, None] * mean.unsqueeze(-3) + scatter
    return torch.linalg.inv(draw_wishart_given(pool.unsqueeze(-1) + d + 1 + counts, psi, generator))


def draw_shared_mean(
    log_pool: Tensor, covs: Tensor, df0: float, scale0_inv: Tensor, generator: torch.Generator
) -> Tensor:
    """Exact draw of a shared covariance ``S``: its ``Wishart(df0, scale0)`` prior is conjugate to
    ``S_c ~ InvWishart(pool + d + 1, pool S)``."""
    num_classes, d = covs.shape[-3], covs.shape[-1]
    pool = log_pool.exp()
    df = df0 + num_classes * (pool + d + 1)
    return draw_wishart_given(df, scale0_inv + pool[..., None, None] * torch.linalg.inv(covs).sum(-3), generator)
