"""The sequence-aware model's sampler as a ``pyro.infer.mcmc.MCMCKernel``.

Each iteration does, for every chain at once (see :mod:`hbni_pyro.models.sequence.steps`):

1. every sequence's class (look integrated out; labelled ones kept) and then its look;
2. the class means: an exact conditional draw;
3. a random walk on the log pooling with the class spreads integrated out (Robbins-Monro tuned
   towards acceptance 0.44 in warm-up), then exact draws of the class spreads ``B_c`` and of
   the shared spread ``B``;
4. the frames' covariance ``W``: an exact conditional draw.

Adapted to a new place (``shift_prior``, :mod:`hbni_pyro.models.sequence.shift_prior`), the class means' prior mean is the old
place's looks moved by a shared scale and offset, drawn before the class means, and a swap move of every pair of
classes follows (:mod:`hbni_pyro.models.sequence.shift_steps`); with ``prevalence``, the class mix is learnt too, drawn
after the classes.

Every conditional draw is an MH move whose proposal is the conditional itself, accepted with
probability 1. Frames enter only through per-sequence statistics, computed once.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.mcmc.base import AdaptiveWalk, BatchedKernel, flatten_chains, fraction
from hbni_pyro.models.sequence.program import SITES, SequenceStats, hyper_scales, look_prior_mean
from hbni_pyro.models.sequence.steps import (
    SequenceState,
    between_data,
    draw_class_covs,
    draw_locs,
    draw_shared_mean,
    draw_within,
    update_classes_and_looks,
    update_pooling,
)
from hbni_pyro.models.sequence.shift_prior import ShiftPrior
from hbni_pyro.models.sequence.shift_steps import draw_prevalence, draw_shift, relabel, shifted_mean
from hbni_pyro.models.sequence.wishart import sample_wishart
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float


class SequenceMetropolis(BatchedKernel):
    """Vectorised sampler for the sequence-aware posterior (see :mod:`hbni_pyro.models.sequence.program`).

    ``MCMC(kernel, num_samples, warmup_steps).run(stats)`` with a :class:`SequenceStats` of ``K``
    sequences (tensors ``(K, ...)``, shared by every chain) or of ``D`` datasets (``(D, K, ...)``), on the
    device where the chains run.
    Sites returned per iteration: ``loc (C, M, d)``, ``between (C, M, d, d)``, ``between_mean (C, d, d)``,
    ``between_pooling (C,)``, ``within (C, d, d)``; with ``shift_prior`` also ``shift_scale (C,)`` and
    ``shift_offset (C, d)``, with ``prevalence`` the class mix ``prevalence (C, M)`` (:attr:`summary_sites`).

    Args (beyond :class:`~hbni_pyro.mcmc.base.BatchedKernel`'s):
        shift_prior: the class means' prior of a model adapted to a new place (``None``: the hyperprior's, around
            the vertices).
        prevalence: the concentration of a symmetric Dirichlet prior on the class mix, which is then learnt and
            used in place of ``class_prior`` in the fit (``None``: the mix is ``class_prior``).
    """

    moves = ("pooling",)

    def __init__(
        self,
        num_chains: int = 16,
        hyperprior: HyperPrior = HyperPrior(),
        class_prior: Tensor | None = None,
        seed: int = 0,
        *,
        shift_prior: ShiftPrior | None = None,
        prevalence: float | None = None,
    ) -> None:
        super().__init__(num_chains, hyperprior, class_prior, seed)
        if shift_prior is not None and not isinstance(shift_prior, ShiftPrior):
            raise TypeError(f"shift_prior: expected a ShiftPrior or None, got {type(shift_prior).__name__}")
        self.shift_prior = shift_prior
        self.prevalence = None if prevalence is None else as_float("prevalence", prevalence, 0.0, low_open=True)
        self.summary_sites = (("shift_scale", "shift_offset") if shift_prior else ()) + (
            ("prevalence",) if prevalence is not None else ()
        )
        """Sites a fit summarises in the posterior's ``info`` rather than keeping their draws."""
        self.save_params = sorted(SITES + self.summary_sites)

    def setup(self, warmup_steps: int, stats: SequenceStats) -> None:
        if stats.count.dim() == 1:
            stats = SequenceStats(*(t.unsqueeze(0) for t in stats))
        num_classes, device = stats.sum_y.shape[-1] + 1, stats.count.device
        if self.shift_prior is not None and self.shift_prior.num_classes != num_classes:
            raise ValueError(
                f"shift_prior: expected an anchor of {num_classes} classes to match the data, got "
                f"{self.shift_prior.num_classes}"
            )
        self._begin(warmup_steps, stats.count.shape[0], num_classes, device)
        self.stats = SequenceStats(*(t.unsqueeze(1) for t in stats))
        self._scales = hyper_scales(self.hyperprior, num_classes - 1, device=device)
        self._between_scale_inv = torch.linalg.inv(self._scales["between_scale"])
        self._prior_mean = (
            look_prior_mean(num_classes, self.hyperprior.look_vertex, device=device)
            if self.shift_prior is None
            else self.shift_prior.anchor.to(device)
        )
        self._shift = (  # the shared scale and offset of a shift prior: at the old place's looks to start
            torch.ones(self.batch, dtype=DTYPE, device=device),
            torch.zeros(self.batch + (num_classes - 1,), dtype=DTYPE, device=device),
        )
        if self.prevalence is not None:
            self.log_prior = self.log_prior.expand(self.batch + (1, num_classes)).clone()
        self._walk = AdaptiveWalk(self.batch, 0.44, device=device)
        self.label_counts = torch.zeros(self.batch[0], stats.count.shape[-1], num_classes, dtype=DTYPE, device=device)
        self.state = self._initial_state(num_classes)

    def _initial_state(self, M: int) -> SequenceState:
        """Shared covariances and the pooling from their priors, class spreads at the shared one,
        class means near their prior mean; then classes and looks from their conditionals."""
        g, h, sc, b = self._gen, self.hyperprior, self._scales, self.batch
        d, like = M - 1, dict(dtype=DTYPE, device=self.device)
        eye = torch.eye(d, **like)
        log_pool = (
            math.log(h.between_pooling_median) + h.between_pooling_sd * torch.randn(b, generator=g, **like)
        ).clamp(-2, 7)
        mean = sample_wishart(
            torch.full(b, sc["between_df"], **like),
            torch.linalg.cholesky(sc["between_scale"]).expand(b + (d, d)),
            g,
        )
        within_prec = sample_wishart(
            torch.full(b, sc["within_df"], **like),
            torch.linalg.cholesky(torch.linalg.inv(sc["within_psi"])).expand(b + (d, d)),
            g,
        )
        loc = self._prior_mean + 0.1 * torch.randn(b + (M, d), generator=g, **like)
        K = self.stats.count.shape[-1]
        mean = mean + 1e-3 * eye
        state = SequenceState(
            torch.zeros(b + (K,), dtype=torch.long, device=self.device),
            torch.zeros(b + (K, d), **like),
            loc,
            mean.unsqueeze(-3).expand(b + (M, d, d)).clone(),
            mean,
            log_pool,
            torch.linalg.inv(within_prec),
        )
        c, look = update_classes_and_looks(state, self.stats, self.log_prior, g)
        return state._replace(c=c, look=look)

    def _params(self) -> dict[str, Tensor]:
        s = self.state
        sites = {
            "loc": s.loc,
            "between": s.between,
            "between_mean": s.between_mean,
            "between_pooling": s.log_pooling.exp(),
            "within": s.within,
        }
        if self.shift_prior is not None:
            sites["shift_scale"], sites["shift_offset"] = self._shift
        if self.prevalence is not None:
            sites["prevalence"] = self.log_prior.squeeze(-2).exp()
        return {k: flatten_chains(v) for k, v in sites.items()}

    def _step(self, warm: bool) -> dict[str, Tensor]:
        g, h, sc, s = self._gen, self.hyperprior, self._scales, self.state
        c, look = update_classes_and_looks(s, self.stats, self.log_prior, g)
        s = s._replace(c=c, look=look)
        if self.prevalence is not None:
            self.log_prior = draw_prevalence(c, s.loc.shape[-2], self.prevalence, g)
        prior_mean, prior_sd = self._prior_mean, h.look_sd
        if self.shift_prior is not None:
            self._shift = draw_shift(s.loc, self.shift_prior, g)
            prior_mean, prior_sd = shifted_mean(self.shift_prior, *self._shift), self.shift_prior.shift_sd
        s = s._replace(loc=draw_locs(s, prior_mean, prior_sd, g))
        counts, scatter = between_data(s)
        log_pool, accepted = update_pooling(
            s.log_pooling,
            s.between_mean,
            counts,
            scatter,
            h.between_pooling_median,
            h.between_pooling_sd,
            self._walk.step,
            g,
        )
        between = draw_class_covs(log_pool, s.between_mean, counts, scatter, g)
        s = s._replace(
            log_pooling=log_pool,
            between=between,
            between_mean=draw_shared_mean(log_pool, between, sc["between_df"], self._between_scale_inv, g),
        )
        s = s._replace(within=draw_within(s, self.stats, sc["within_df"], sc["within_psi"], g))
        if self.shift_prior is not None:
            learnt = self.log_prior if self.prevalence is not None else None
            s, learnt, _ = relabel(s, self.stats, prior_mean, prior_sd, learnt, g)
            self.log_prior = self.log_prior if learnt is None else learnt
        self.state = s
        c = s.c
        if warm:
            self._walk.adapt(accepted, self._t)
        else:
            index = c.transpose(1, 2)
            self.label_counts.scatter_add_(-1, index, torch.ones(index.shape, dtype=DTYPE, device=index.device))
        return {"pooling": fraction(accepted)}

    @property
    def label_probs(self) -> Tensor:
        """``(D, K, M)`` post-warm-up frequency of each sequence's class, pooled over a dataset's chains."""
        return self.label_counts / (self.draws_done * self.batch[1])
