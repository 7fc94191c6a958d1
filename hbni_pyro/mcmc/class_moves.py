"""The class move every frame-level kernel shares (the paper's and the confusion-aware model's), vectorised over
chains: an MH move of every unknown class label, the per-class sufficient statistics, and :class:`FrameData`,
a dataset split into the outputs whose class moves and the labelled ones reduced to statistics.

Every function takes the current state and data, draws from an explicit generator (on the data's device, where
everything is computed) and returns the new values and acceptance indicators. :func:`update_classes` rewrites the
classes in place (see there). Shapes: any leading batch ``...`` (chains, or datasets x chains), ``N`` unlabelled
outputs, ``M`` classes; data broadcast against the state (one dataset shared by every chain, or one each).

Labelled outputs never enter a step one by one: their per-class sufficient statistics (``known_counts``,
``known_sums``) are computed once and added to those of the outputs whose class the chain currently assigns. The
class move runs over the unlabelled outputs in blocks of :data:`BLOCK_ELEMENTS` (chain, output) pairs, so its
temporaries stay small however many outputs and chains there are. On the CPU the move is compiled
(:mod:`hbni_pyro.mcmc.class_move_numba`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from hbni_pyro.distributions.density import concentrations, dirichlet_terms, lifted_normaliser
from hbni_pyro.mcmc.class_move_numba import class_move_stats
from hbni_pyro.validation import DTYPE


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


class FrameData:
    """Outputs of ``D`` datasets split into what moves and what is known, for the frame-level kernels.

    Rows labelled in every dataset are reduced once to per-class counts and log-output sums;
    the other rows (unlabelled in some dataset) keep their own class moves. Everything lives on
    ``obs``'s device; on the CPU the class move is the compiled one (:func:`class_move_stats`).

    Attributes:
        data: the :class:`MHData` (tensors ``(D, 1, ...)``).
        free: ``(N,)`` bool, the rows kept as outputs; ``known_labels (D, N)`` the given labels.
    """

    def __init__(self, obs: Tensor, labels: Tensor | None, log_prior: Tensor) -> None:
        D, N, M = obs.shape
        device = obs.device
        labels = torch.full((D, N), -1, dtype=torch.long, device=device) if labels is None else labels.expand(D, N)
        self.known_labels = labels
        self.free = (labels < 0).any(0)
        fixed = ~self.free
        counts, sums = sufficient_stats(labels[:, fixed], obs[:, fixed].log(), full=True)
        self.num_classes = M
        self.data = frame_data(
            obs[:, self.free].unsqueeze(1),
            labels[:, self.free].unsqueeze(1),
            log_prior,
            counts.unsqueeze(1),
            sums.unsqueeze(1),
        )
        self.label_counts = torch.zeros(D, int(self.free.sum()), M, dtype=DTYPE, device=device)
        self.compiled = device.type == "cpu"
        if self.compiled:
            d = self.data
            self._arrays = tuple(
                np.ascontiguousarray(t[:, 0].numpy())
                for t in (d.labels, d.log_obs, d.log_proposal, d.alias_prob, d.alias)
            )

    def compiled_move(
        self, c: Tensor, log_theta: Tensor, stay_prob: float, seed: int, iteration: int, record: bool
    ) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        """The class move of every chain on the CPU (:func:`class_move_stats`), in place on ``c (D, Cp, N)``;
        returns the accepted moves and the statistics ``counts, sums (D, Cp, M)``, recording the labels if asked."""
        theta = log_theta.exp()
        offset = lifted_normaliser(theta, self.num_classes) + self.data.log_prior
        classes = c.numpy().transpose(0, 2, 1)  # (D, N, Cp): a view if c is stored outputs_major, else copied back
        work = classes if classes.flags.c_contiguous else np.ascontiguousarray(classes)
        counts, sums, accepted = class_move_stats(
            work,
            *self._arrays,
            np.ascontiguousarray(offset.numpy()),
            np.ascontiguousarray(theta.numpy()),
            stay_prob,
            np.uint64(seed),
            np.int64(iteration),
            self.label_counts.numpy(),
            record,
        )
        if work is not classes:
            classes[...] = work
        return torch.from_numpy(accepted).sum(), (torch.from_numpy(counts), torch.from_numpy(sums))

    def initial_classes(self, batch: tuple[int, int]) -> Tensor:
        """``(D, Cp, N_free)`` initial classes: each unknown output's largest entry (given labels kept).

        Every chain starts its classes there (its parameters start dispersed, drawn from the prior). Classes drawn
        from the proposal weights instead put most outputs of a large noisy dataset in a wrong class (many more than
        the largest entry does), and a chain whose first ``theta`` was small then drifted to a state of near-uniform
        classes and ``theta`` near 0 that it did not leave: a tiny share of the posterior in which some chains of
        large unlabelled fits settled (``benchmarks/bench_fit_scale.py`` fits such data; their split R-hat says
        so)."""
        d = self.data
        c0 = d.log_proposal.argmax(-1).expand(batch + d.labels.shape[-1:])
        return torch.where(d.labels >= 0, d.labels, c0)

    @staticmethod
    def outputs_major(c: Tensor) -> Tensor:
        """``c (D, Cp, N)`` stored with each output's chains adjacent, as :func:`class_move_stats` reads them in place."""
        return c.transpose(1, 2).contiguous().transpose(1, 2)

    def record(self, c: Tensor) -> None:
        """Add the current classes ``(D, Cp, N_free)`` of every chain to the label counts."""
        index = c.transpose(1, 2)
        self.label_counts.scatter_add_(-1, index, torch.ones((), dtype=DTYPE, device=index.device).expand(index.shape))

    def label_probs(self, draws: int, chains: int) -> Tensor:
        """``(D, N, M)`` posterior frequency of each row's class (labelled rows one-hot)."""
        D = self.known_labels.shape[0]
        out = torch.zeros(D, self.free.shape[0], self.num_classes, dtype=DTYPE, device=self.label_counts.device)
        fixed = ~self.free
        out[:, fixed] = torch.nn.functional.one_hot(self.known_labels[:, fixed], self.num_classes).to(DTYPE)
        out[:, self.free] = self.label_counts / (draws * chains)
        return out
