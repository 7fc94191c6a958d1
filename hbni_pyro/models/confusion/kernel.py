"""Metropolis-Hastings for the confusion-aware model as a ``pyro.infer.mcmc.MCMCKernel``.

Each iteration does, for every chain at once:

1. the paper's MH move on every unknown class label (with the full concentration vectors);
2. a random walk on every entry of the concentration matrix (``log theta_c`` on the diagonal,
   ``log beta_cj`` off it), one column at a time (rows are independent given the classes);
3. the paper's joint random walk on ``(log kappa, log gamma)`` given ``theta``;
4. an exact conditional draw of ``beta_loc`` (conjugate normal) and a random walk on
   ``log beta_scale``.

Step sizes adapt in warm-up (Robbins-Monro, towards 0.44 for 1-D moves and 0.35 for the
2-D move) and are frozen afterwards. Labelled outputs enter only through per-class counts
and log-output sums computed once in ``setup``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import gamma_variates
from hbni_pyro.mcmc.base import AdaptiveWalk, AdaptiveWalk2D, BatchedKernel, flatten_chains, fraction
from hbni_pyro.mcmc.class_moves import FrameData, MHState, sufficient_stats, update_classes
from hbni_pyro.models.confusion.steps import (
    draw_beta_loc,
    off_diagonal_logs,
    split_conc,
    update_beta_scale,
    update_concentrations,
)
from hbni_pyro.mcmc.hyper_move import update_hyper
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float


class ConfusionMetropolis(BatchedKernel):
    """Vectorised MH kernel for the confusion-aware posterior (see :mod:`hbni_pyro.models.confusion.program`).

    Same data contract as :class:`~hbni_pyro.models.paper.kernel.HBNIMetropolis`. Sites returned per
    iteration: ``theta (C, M)``, ``beta (C, M, M)`` (unit diagonal), ``kappa``, ``gamma``,
    ``beta_loc``, ``beta_scale`` ``(C,)``.
    """

    moves = ("c", "conc", "hyper", "beta_scale")

    def __init__(
        self,
        num_chains: int = 16,
        hyperprior: HyperPrior = HyperPrior(),
        class_prior: Tensor | None = None,
        stay_prob: float = 0.5,
        seed: int = 0,
    ) -> None:
        super().__init__(num_chains, hyperprior, class_prior, seed)
        self.stay_prob = as_float("stay_prob", stay_prob, 0.0, 1.0, high_open=True)
        self.save_params = ["beta", "beta_loc", "beta_scale", "gamma", "kappa", "theta"]

    def setup(self, warmup_steps: int, obs: Tensor, labels: Tensor | None = None) -> None:
        obs = obs if obs.dim() == 3 else obs.unsqueeze(0)
        labels = labels if labels is None or labels.dim() == 2 else labels.unsqueeze(0)
        M = obs.shape[-1]
        self._begin(warmup_steps, obs.shape[0], M, obs.device)
        self.frames = FrameData(obs, labels, self.log_prior)
        self._init_state(M)
        self._walk_conc = AdaptiveWalk(self.batch + (M, M), 0.44, device=obs.device)
        self._walk_hyper = AdaptiveWalk2D(self.batch, device=obs.device)
        self._walk_scale = AdaptiveWalk(self.batch, 0.44, device=obs.device)
        self._class_moves = int((self.frames.data.labels < 0).sum()) * self.batch[1]

    def _init_state(self, M: int) -> None:
        """Hyperparameters and concentrations from the prior (clamped to a sane range), classes
        from the proposal weights."""
        g, hp, b, device = self._gen, self.hyperprior, self.batch, self.device
        kappa = gamma_variates(torch.full(b, hp.beta, device=device), hp.eta, g).clamp(0.05, 50)
        gamma = gamma_variates(torch.full(b, hp.nu, device=device), hp.omega, g).clamp(0.05, 500)
        theta = gamma_variates(kappa.unsqueeze(-1).expand(b + (M,)), gamma.unsqueeze(-1), g).clamp(0.1, 1000)
        self.beta_loc = (hp.offdiag_loc_sd * torch.randn(b, generator=g, dtype=DTYPE, device=device)).clamp(-2, 2)
        self.log_beta_scale = (
            (hp.offdiag_scale_sd * torch.randn(b, generator=g, dtype=DTYPE, device=device)).abs().clamp(0.05, 2).log()
        )
        log_beta = self.beta_loc[..., None, None] + self.log_beta_scale.exp()[..., None, None] * torch.randn(
            b + (M, M), generator=g, dtype=DTYPE, device=device
        )
        eye = torch.eye(M, dtype=torch.bool, device=device)
        self.log_conc = torch.where(eye, theta.log().diag_embed(), log_beta.clamp(-4, 3))
        self.c = self.frames.initial_classes(b)
        self.log_kappa, self.log_gamma = kappa.log(), gamma.log()

    def _params(self) -> dict[str, Tensor]:
        theta, beta = split_conc(self.log_conc)
        sites = {
            "theta": theta,
            "beta": beta,
            "kappa": self.log_kappa.exp(),
            "gamma": self.log_gamma.exp(),
            "beta_loc": self.beta_loc,
            "beta_scale": self.log_beta_scale.exp(),
        }
        return {k: flatten_chains(v) for k, v in sites.items()}

    def _step(self, warm: bool) -> dict[str, Tensor]:
        g, hp, data = self._gen, self.hyperprior, self.frames.data
        theta, beta = split_conc(self.log_conc)
        state = MHState(self.c, theta.log(), self.log_kappa, self.log_gamma)
        self.c, acc_c = update_classes(state, data, self.stay_prob, g, beta=beta)
        counts, sums = sufficient_stats(self.c, data.log_obs, full=True)
        counts, sums = counts + data.known_counts, sums + data.known_sums
        scale = self.log_beta_scale.exp()
        self.log_conc, acc_conc = update_concentrations(
            self.log_conc,
            counts,
            sums,
            self.log_kappa.exp(),
            self.log_gamma.exp(),
            self.beta_loc,
            scale,
            self._walk_conc.step,
            g,
        )
        state = state._replace(log_theta=self.log_conc.diagonal(dim1=-2, dim2=-1))
        self.log_kappa, self.log_gamma, acc_h = update_hyper(state, hp, self._walk_hyper.chol, g)
        log_beta = off_diagonal_logs(self.log_conc)
        self.beta_loc = draw_beta_loc(log_beta, scale, hp.offdiag_loc_sd, g)
        self.log_beta_scale, acc_s = update_beta_scale(
            self.log_beta_scale, log_beta, self.beta_loc, hp.offdiag_scale_sd, self._walk_scale.step, g
        )
        if warm:
            self._walk_conc.adapt(acc_conc, self._t)
            self._walk_hyper.adapt(
                torch.stack([self.log_kappa, self.log_gamma], -1), acc_h, self._t, self._warmup_steps
            )
            self._walk_scale.adapt(acc_s, self._t)
        else:
            self.frames.record(self.c)
        return {
            "c": fraction(acc_c, self._class_moves),
            "conc": fraction(acc_conc),
            "hyper": fraction(acc_h),
            "beta_scale": fraction(acc_s),
        }

    @property
    def label_probs(self) -> Tensor:
        """``(D, N, M)`` post-warm-up frequency of each class for each output, pooled over a dataset's chains."""
        return self.frames.label_probs(self.draws_done, self.batch[1])
