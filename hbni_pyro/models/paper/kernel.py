"""The paper's Metropolis-Hastings sampler for HBNI as a ``pyro.infer.mcmc.MCMCKernel``.

Each iteration does, for every chain at once:

1. an MH move on every unknown class label ``c_i`` (a categorical proposal that keeps the
   current class with probability ``stay_prob``, otherwise draws from ``w_i = (o_i + 1/M) / 2``,
   with the Hastings correction for that asymmetric proposal);
2. a Gaussian random walk on every ``log theta_m``;
3. a joint Gaussian random walk on ``(log kappa, log gamma)``.

During warm-up the step sizes follow Robbins-Monro updates towards acceptance 0.44 (1-D
moves) and 0.35 (the 2-D hyper move), and the hyper move's covariance is learnt from each
chain's own warm-up draws; everything is frozen afterwards, so the post-warm-up chain is
a plain time-homogeneous MH chain. Labelled outputs enter only through per-class sufficient
statistics computed once in ``setup``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import gamma_variates
from hbni_pyro.mcmc.base import AdaptiveWalk, AdaptiveWalk2D, BatchedKernel, flatten_chains, fraction
from hbni_pyro.mcmc.class_moves import FrameData, MHState, update_classes
from hbni_pyro.mcmc.hyper_move import update_hyper
from hbni_pyro.models.paper.steps import update_theta
from hbni_infra.checks import as_float


class HBNIMetropolis(BatchedKernel):
    """Vectorised MH kernel for the HBNI posterior ``p(c, theta, kappa, gamma | obs)``.

    Args:
        num_chains, hyperprior, class_prior, seed: see :class:`~hbni_pyro.mcmc.base.BatchedKernel`.
        stay_prob: probability that a class proposal keeps the current class.

    ``MCMC(kernel, num_samples, warmup_steps).run(obs, labels)`` with validated ``obs`` of shape
    ``(N, M)`` (shared by every chain) or ``(D, N, M)`` (``num_chains / D`` chains per dataset) and
    optional ``labels`` ``(N,)`` / ``(D, N)`` with -1 for unknown, on one device, where the chains run.
    Sites returned per iteration: ``theta (C, M)``, ``kappa (C,)``, ``gamma (C,)``.
    """

    moves = ("c", "theta", "hyper")

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
        self.save_params = ["gamma", "kappa", "theta"]

    def setup(self, warmup_steps: int, obs: Tensor, labels: Tensor | None = None) -> None:
        obs = obs if obs.dim() == 3 else obs.unsqueeze(0)
        labels = labels if labels is None or labels.dim() == 2 else labels.unsqueeze(0)
        self._begin(warmup_steps, obs.shape[0], obs.shape[-1], obs.device)
        self.frames = FrameData(obs, labels, self.log_prior)
        self._state = self._initial_state(obs.shape[-1])
        self._walk_theta = AdaptiveWalk(self.batch + (obs.shape[-1],), 0.44, device=obs.device)
        self._walk_hyper = AdaptiveWalk2D(self.batch, device=obs.device)
        self._class_moves = int((self.frames.data.labels < 0).sum()) * self.batch[1]

    def _initial_state(self, num_classes: int) -> MHState:
        g, hp = self._gen, self.hyperprior
        C = self.num_chains
        kappa = gamma_variates(torch.full((C,), hp.beta, device=self.device), hp.eta, g).clamp(0.05, 50)
        gamma = gamma_variates(torch.full((C,), hp.nu, device=self.device), hp.omega, g).clamp(0.05, 500)
        theta = gamma_variates(kappa.unsqueeze(-1).expand(C, num_classes), gamma.unsqueeze(-1), g)
        c = self.frames.initial_classes(self.batch)
        return MHState(
            self.frames.outputs_major(c) if self.frames.compiled else c,
            theta.clamp(0.1, 1000).log().reshape(self.batch + (-1,)),
            kappa.log().reshape(self.batch),
            gamma.log().reshape(self.batch),
        )

    def _params(self) -> dict[str, Tensor]:
        s = self._state
        return {
            k: flatten_chains(v.exp())
            for k, v in (("theta", s.log_theta), ("kappa", s.log_kappa), ("gamma", s.log_gamma))
        }

    def _step(self, warm: bool) -> dict[str, Tensor]:
        s, g, data, frames = self._state, self._gen, self.frames.data, self.frames
        if frames.compiled:
            acc_c, stats = frames.compiled_move(s.c, s.log_theta, self.stay_prob, self.seed, self._t, not warm)
        else:
            (c, acc_c), stats = update_classes(s, data, self.stay_prob, g), None
            s = s._replace(c=c)
        log_theta, acc_t = update_theta(s, data, self._walk_theta.step, g, stats)
        s = s._replace(log_theta=log_theta)
        log_kappa, log_gamma, acc_h = update_hyper(s, self.hyperprior, self._walk_hyper.chol, g)
        self._state = s._replace(log_kappa=log_kappa, log_gamma=log_gamma)
        if warm:
            self._walk_theta.adapt(acc_t, self._t)
            x = torch.stack([log_kappa, log_gamma], -1)
            self._walk_hyper.adapt(x, acc_h, self._t, self._warmup_steps)
        elif not frames.compiled:
            frames.record(s.c)
        return {"c": fraction(acc_c, self._class_moves), "theta": fraction(acc_t), "hyper": fraction(acc_h)}

    @property
    def label_probs(self) -> Tensor:
        """``(D, N, M)`` post-warm-up frequency of each class for each output, pooled over a dataset's chains."""
        return self.frames.label_probs(self.draws_done, self.batch[1])

    def diagnostics(self) -> dict:
        return {
            **super().diagnostics(),
            "step size theta": self._walk_theta.step.reshape(-1, self._walk_theta.step.shape[-1]).mean(0).tolist(),
            "step scale hyper": float(self._walk_hyper.log_scale.exp().mean()),
        }
