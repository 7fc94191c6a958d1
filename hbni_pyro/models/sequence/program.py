"""The sequence-aware noise model: each sequence has a latent look, so its frames are exchangeable.

Outputs live in their ``d = M - 1`` isometric log-ratio coordinates ``y = ilr(o)``:

    m_c  ~ N(look_vertex * u_c, look_sd^2 I)      class c's mean look (u_c: towards vertex c)
    B    ~ Wishart(...),  lam ~ LogNormal(...)    shared spread of looks, and how hard it pools
    B_c  ~ InvWishart(lam + d + 1, lam B)         class c's spread of looks (mean B)
    W    ~ InvWishart(...)                        how frames scatter around their sequence's look
    c_k  ~ Cat(p)                                 sequence k's class (known, or enumerated)
    mu_k ~ N(m_{c_k}, B_{c_k})                    sequence k's look: its view, light and background
    y_ki ~ N(mu_k, W)                             its frames

Frames of one sequence share ``mu_k``: given the class they are exchangeable, not independent,
and the evidence in their mean look saturates once the look is known (``B_c + W / n -> B_c``).
The frames' scatter around the look is the same for every class, so it carries no evidence
about the class: a class-specific ``W_c`` lets evidence from that scatter grow with every frame,
and frames of a moving camera are correlated in time, so it grows too fast (a lower held-out log score on the
mission's in-flight sequences than with one ``W``).
The fit keeps the frames exchangeable given the look; the filter and the predictive streams add
the AR(1) correlation of frames about it that the fit estimates apart (:mod:`hbni_pyro.models.sequence.correlation`).
A class's mean look is a full vector, so the model is confusion-aware as well: the looks of
medical and news copters may lie close together, those of copters and crates far apart.

Integrating ``mu_k`` out, a sequence's ``n`` frames enter only through ``n``, ``sum y`` and
``sum y y^T`` (:func:`.looks.look_log_marginal` and :func:`~.looks.within_log_prob`); the Pyro program does the same (:class:`TwoLevelSequence`), so NUTS explores only the global
parameters, and samples the covariances through their Cholesky factors. Defaults are in
:class:`~hbni_pyro.HyperPrior`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import pyro
import pyro.distributions as dist
import torch
from pyro.distributions.torch_distribution import TorchDistribution
from torch import Tensor
from torch.distributions import constraints

from hbni_pyro.distributions.density import helmert_basis, ilr, ilr_log_jacobian, normal_log_prob
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.models.sequence.looks import look_basis, look_log_marginal, scatter_trace, within_log_prob
from hbni_pyro.models.sequence.wishart import (
    InvWishartCholesky,
    WishartCholesky,
    inv_wishart_log_prob,
    logdet_spd,
    wishart_log_prob,
)

SITES = ("loc", "between", "between_mean", "between_pooling", "within")
"""Posterior sites: ``loc (M, d)``, ``between (M, d, d)``, ``between_mean (d, d)``, ``between_pooling ()``,
``within (d, d)``."""


class SequenceStats(NamedTuple):
    """Per-sequence sufficient statistics of the frames' log-ratio coordinates.

    ``count (..., K)`` frames, ``sum_y (..., K, d)``, ``sum_yy (..., K, d, d)``, ``labels (..., K)`` (-1 unknown).
    """

    count: Tensor
    sum_y: Tensor
    sum_yy: Tensor
    labels: Tensor

    @property
    def mean_y(self) -> Tensor:
        return self.sum_y / self.count.unsqueeze(-1)

    @property
    def scatter(self) -> Tensor:
        """``sum_i (y_i - ybar)(y_i - ybar)^T`` per sequence ``(..., K, d, d)``."""
        m = self.mean_y
        return self.sum_yy - self.count[..., None, None] * m.unsqueeze(-1) * m.unsqueeze(-2)


def sequence_stats(obs: Tensor, sequence_ids: Tensor, labels: Tensor, num_sequences: int) -> SequenceStats:
    """One pass over validated outputs ``obs (N, M)``: statistics of each sequence ``0..K-1``, on ``obs``'s device.

    ``sequence_ids (N,)`` in ``[0, K)``; ``labels (N,)`` constant within a sequence (-1 unknown).
    """
    y = ilr(obs)
    d = y.shape[-1]
    like = dict(dtype=obs.dtype, device=obs.device)
    count = torch.zeros(num_sequences, **like).index_add_(0, sequence_ids, torch.ones_like(y[:, 0]))
    sum_y = torch.zeros(num_sequences, d, **like).index_add_(0, sequence_ids, y)
    sum_yy = torch.zeros(num_sequences, d * d, **like)
    for start in range(0, y.shape[0], 1 << 16):  # y y^T in chunks: never an (N, d, d) tensor
        block = y[start : start + (1 << 16)]
        sum_yy.index_add_(
            0, sequence_ids[start : start + (1 << 16)], (block.unsqueeze(-1) * block.unsqueeze(-2)).flatten(1)
        )
    seq_labels = torch.full((num_sequences,), -1, dtype=torch.long, device=obs.device).scatter_(0, sequence_ids, labels)
    return SequenceStats(count, sum_y, sum_yy.reshape(num_sequences, d, d), seq_labels)


def look_prior_mean(
    num_classes: int, look_vertex: float, dtype: torch.dtype = torch.float64, device: torch.device | None = None
) -> Tensor:
    """``(M, d)`` prior mean of the class looks: ``look_vertex`` along each vertex's unit direction."""
    basis = helmert_basis(num_classes, dtype, device).T  # (M, d): row c = ilr direction of vertex c
    return look_vertex * basis / basis.norm(dim=-1, keepdim=True)


def hyper_scales(
    hp: HyperPrior, d: int, dtype: torch.dtype = torch.float64, device: torch.device | None = None
) -> dict[str, Tensor | float]:
    """The sequence model's hyperparameters as matrices (on ``device``): Wishart ``df`` and ``scale`` of ``B``,
    inverse-Wishart ``df`` and ``psi`` of ``W``."""
    eye = torch.eye(d, dtype=dtype, device=device)
    between_df = d + hp.between_df
    return {
        "between_df": float(between_df),
        "between_scale": hp.between_scale / between_df * eye,
        "within_df": float(d + 1 + hp.within_df),
        "within_psi": hp.within_df * hp.within_scale * eye,
    }


class TwoLevelSequence(TorchDistribution):
    """A padded sequence of outputs ``(T, M)`` whose look ``mu ~ N(loc, between)`` is integrated out,
    frames ``ilr(o) ~ N(mu, within)``; ``mask (..., T)`` marks the real frames.

    ``log_prob`` is :func:`~hbni_pyro.models.sequence.looks.look_log_marginal` plus
    :func:`~hbni_pyro.models.sequence.looks.within_log_prob` plus the frames' log-ratio Jacobians.
    """

    arg_constraints = {"loc": constraints.real_vector}
    support = constraints.independent(constraints.simplex, 1)

    def __init__(
        self, loc: Tensor, between: Tensor, within: Tensor, mask: Tensor, validate_args: bool | None = None
    ) -> None:
        batch = torch.broadcast_shapes(loc.shape[:-1], between.shape[:-2], within.shape[:-2], mask.shape[:-1])
        self.loc, self.between, self.within, self.mask = loc, between, within, mask
        super().__init__(batch, torch.Size([mask.shape[-1], loc.shape[-1] + 1]), validate_args=validate_args)

    def expand(self, batch_shape, _instance=None):
        return TwoLevelSequence(
            self.loc, self.between, self.within, self.mask.expand(torch.Size(batch_shape) + self.mask.shape[-1:])
        )

    def log_prob(self, value: Tensor) -> Tensor:
        m = self.mask.to(value.dtype)
        y = ilr(value) * m.unsqueeze(-1)
        count = m.sum(-1)
        mean_y = y.sum(-2) / count.unsqueeze(-1)
        scatter = y.transpose(-1, -2) @ y - count[..., None, None] * mean_y.unsqueeze(-1) * mean_y.unsqueeze(-2)
        basis, lam, logdet = look_basis(self.between, self.within)
        resid = (basis @ (mean_y - self.loc).unsqueeze(-1)).squeeze(-1)
        look = look_log_marginal(count, resid, lam, logdet)
        rest = within_log_prob(count, scatter_trace(torch.linalg.inv(self.within), scatter), logdet, self.loc.shape[-1])
        return look + rest + (ilr_log_jacobian(value) * m).sum(-1)


def sequence_model(
    obs: Tensor,
    mask: Tensor,
    labels: Tensor | None = None,
    class_prior: Tensor | None = None,
    hyperprior: HyperPrior = HyperPrior(),
) -> None:
    """Pyro model of ``K`` padded sequences ``obs (K, T, M)`` with ``mask (K, T)`` (True = a real frame)
    and optional per-sequence ``labels (K,)`` (-1 = unknown, enumerated in parallel).

    ``max_plate_nesting=1``. Padding must be on the simplex. The looks are integrated out.
    """
    num_seq, _, num_classes = obs.shape
    d = num_classes - 1
    h, sc = hyperprior, hyper_scales(hyperprior, d, obs.dtype)
    p = class_prior if class_prior is not None else obs.new_full((num_classes,), 1.0 / num_classes)
    pool = pyro.sample(
        "between_pooling",
        dist.LogNormal(obs.new_tensor(math.log(h.between_pooling_median)), obs.new_tensor(h.between_pooling_sd)),
    )
    mean_tril = pyro.sample(
        "between_mean_tril", WishartCholesky(torch.tensor(sc["between_df"], dtype=obs.dtype), sc["between_scale"])
    )
    within_tril = pyro.sample(
        "within_tril", InvWishartCholesky(torch.tensor(sc["within_df"], dtype=obs.dtype), sc["within_psi"])
    )
    with pyro.plate("classes", num_classes, dim=-1):
        loc = pyro.sample(
            "loc",
            dist.MultivariateNormal(
                look_prior_mean(num_classes, h.look_vertex, obs.dtype),
                scale_tril=h.look_sd * torch.eye(d, dtype=obs.dtype),
            ),
        )
        between_tril = pyro.sample("between_tril", InvWishartCholesky(pool + d + 1, pool * mean_tril @ mean_tril.T))
    between = between_tril @ between_tril.transpose(-1, -2)
    within = within_tril @ within_tril.T
    known = torch.zeros(num_seq, dtype=torch.bool) if labels is None else labels >= 0
    for name, rows in (("labelled", known), ("unlabelled", ~known)):
        if not rows.any():
            continue
        with pyro.plate(f"seq_{name}", int(rows.sum()), dim=-1):
            if name == "labelled":
                c = pyro.sample("c_labelled", dist.Categorical(p), obs=labels[rows])
            else:
                c = pyro.sample("c", dist.Categorical(p), infer={"enumerate": "parallel"})
            pyro.sample(f"o_{name}", TwoLevelSequence(loc[c], between[c], within, mask[rows]), obs=obs[rows])


def sequence_prior_log_prob(params: dict[str, Tensor], hyperprior: HyperPrior) -> Tensor:
    """``log p(params)``, densities over the covariances themselves and the pooling, batched over
    leading dims (``loc (..., M, d)`` etc.)."""
    loc, between, mean, pool, within = (params[k] for k in SITES)
    num_classes, d = loc.shape[-2:]
    h, sc = hyperprior, hyper_scales(hyperprior, d, loc.dtype)
    lp = normal_log_prob(loc, look_prior_mean(num_classes, h.look_vertex, loc.dtype), h.look_sd).sum((-1, -2))
    lp = lp + normal_log_prob(pool.log(), math.log(h.between_pooling_median), h.between_pooling_sd) - pool.log()
    lp = lp + wishart_log_prob(
        mean, sc["between_df"], torch.linalg.inv(sc["between_scale"]), logdet_spd(sc["between_scale"])
    )
    lp = lp + inv_wishart_log_prob(torch.linalg.inv(within), sc["within_df"], sc["within_psi"])
    psi = pool[..., None, None, None] * mean.unsqueeze(-3)
    return lp + inv_wishart_log_prob(torch.linalg.inv(between), (pool + d + 1).unsqueeze(-1), psi).sum(-1)


def look_residuals(basis: Tensor, mean_y: Tensor, loc: Tensor) -> Tensor:
    """``A_c (ybar_k - m_c)`` for every sequence and class: ``basis (..., M, d, d)``, ``mean_y (..., K, d)``,
    ``loc (..., M, d)`` -> ``(..., K, M, d)``, by one matmul (no per-sequence copy of the bases)."""
    projected = (basis @ mean_y.unsqueeze(-3).transpose(-1, -2)).permute(*range(basis.dim() - 3), -1, -3, -2)
    return projected - (basis @ loc.unsqueeze(-1)).squeeze(-1).unsqueeze(-3)


def sequence_log_lik(stats: SequenceStats, params: dict[str, Tensor], class_prior: Tensor) -> Tensor:
    """``(..., K, M)``: ``log p_c + log p(frames of sequence k | c, params)`` in log-ratio coordinates,
    the look integrated out. ``params`` holds ``loc (..., M, d)``, ``between (..., M, d, d)`` and ``within (..., d, d)``."""
    within = params["within"].unsqueeze(-3)
    basis, lam, logdet = look_basis(params["between"], within)
    look = look_log_marginal(
        stats.count[..., None],
        look_residuals(basis, stats.mean_y, params["loc"]),
        lam.unsqueeze(-3),
        logdet.unsqueeze(-2),
    )
    trace = scatter_trace(torch.linalg.inv(within).unsqueeze(-4), stats.scatter.unsqueeze(-3))
    rest = within_log_prob(stats.count[..., None], trace, logdet.unsqueeze(-2), within.shape[-1])
    return look + rest + class_prior.log()


def sequence_log_joint(
    stats: SequenceStats, params: dict[str, Tensor], class_prior: Tensor, hyperprior: HyperPrior = HyperPrior()
) -> Tensor:
    """``log p(frames, known labels, params)`` in log-ratio coordinates, looks integrated and unknown classes summed out."""
    per_class = sequence_log_lik(stats, params, class_prior)
    known = stats.labels >= 0
    fixed = per_class.gather(-1, stats.labels.clamp_min(0).expand(per_class.shape[:-1]).unsqueeze(-1)).squeeze(-1)
    marg = torch.where(known, fixed, torch.logsumexp(per_class, -1)).sum(-1)
    return sequence_prior_log_prob(params, hyperprior) + marg
