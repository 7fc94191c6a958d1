"""The paper's Metropolis-Hastings sampler for HBNI as a ``pyro.infer.mcmc.MCMCKernel``.

One kernel instance advances ``num_chains`` chains together in one tensor program (the
``pyro.infer.MCMC`` driver runs it as a single "chain" whose sites carry a leading chain
dimension). Each iteration does, for every chain at once:

1. an MH move on every unknown class label ``c_i`` (a categorical proposal that keeps the
   current class with probability ``stay_prob``, otherwise draws from ``w_i = (o_i + 1/M) / 2``,
   with the Hastings correction for that asymmetric proposal);
2. a Gaussian random walk on every ``log theta_m``;
3. a joint Gaussian random walk on ``(log kappa, log gamma)``.

During warm-up the step sizes follow Robbins-Monro updates towards acceptance 0.44 (1-D
moves) and 0.35 (the 2-D hyper move), and the hyper move's covariance is learnt from each
chain's own warm-up draws; everything is frozen afterwards, so the post-warm-up chain is
a plain time-homogeneous MH chain.
"""

from __future__ import annotations

import math

import torch
from pyro.infer.mcmc.mcmc_kernel import MCMCKernel
from torch import Tensor

from hbni_pyro.kernels.mh_steps import MHData, MHState, update_classes, update_hyper, update_theta
from hbni_pyro.generative import gamma_variates
from hbni_pyro.model import HyperPrior
from hbni_pyro.validation import DTYPE

_TARGET_1D = 0.44
_TARGET_2D = 0.35


class HBNIMetropolis(MCMCKernel):
    """Vectorised MH kernel for the HBNI posterior ``p(c, theta, kappa, gamma | obs)``.

    Args:
        num_chains: chains advanced together.
        hyperprior: the :class:`~hbni_pyro.model.HyperPrior`.
        class_prior: ``(M,)`` class prior ``p`` (``None`` = uniform).
        stay_prob: probability that a class proposal keeps the current class.
        seed: seed of the kernel's own ``torch.Generator`` (initial state and every move).

    ``MCMC(kernel, num_samples, warmup_steps).run(obs, labels)`` with validated ``obs`` of shape
    ``(N, M)`` (shared by every chain) or ``(num_chains, N, M)`` (one dataset per chain) and
    optional ``labels`` ``(N,)`` / ``(num_chains, N)`` with -1 for unknown. Sites returned per
    iteration: ``theta (C, M)``, ``kappa (C,)``, ``gamma (C,)``.
    """

    transforms: dict = {}

    def __init__(
        self,
        num_chains: int = 16,
        hyperprior: HyperPrior = HyperPrior(),
        class_prior: Tensor | None = None,
        stay_prob: float = 0.5,
        seed: int = 0,
    ) -> None:
        if not (isinstance(num_chains, int) and num_chains >= 1):
            raise ValueError(f"num_chains: expected a positive int, got {num_chains!r}")
        if not 0 <= stay_prob < 1:
            raise ValueError(f"stay_prob: expected a probability in [0, 1), got {stay_prob!r}")
        self.num_chains = num_chains
        self.hyperprior = hyperprior
        self.class_prior = class_prior
        self.stay_prob = stay_prob
        self.seed = seed
        self.save_params = ["gamma", "kappa", "theta"]

    def setup(self, warmup_steps: int, obs: Tensor, labels: Tensor | None = None) -> None:
        num_classes = obs.shape[-1]
        obs = obs if obs.dim() == 3 else obs.unsqueeze(0)
        if labels is None:
            labels = torch.full(obs.shape[:-1], -1, dtype=torch.long)
        labels = labels if labels.dim() == 2 else labels.unsqueeze(0)
        prior = self.class_prior if self.class_prior is not None else torch.full((num_classes,), 1.0 / num_classes)
        weights = 0.5 * obs + 0.5 / num_classes
        self._data = MHData(obs.log(), labels, prior.to(DTYPE).log(), weights.log(), weights.cumsum(-1))
        self._warmup_steps = warmup_steps
        self._t = 0
        self._gen = torch.Generator().manual_seed(self.seed)
        self._state = self._initial_state(obs.shape[-2], num_classes)
        C = self.num_chains
        self._log_step_theta = torch.full((C, num_classes), math.log(0.5), dtype=DTYPE)
        self._log_scale_hyper = torch.full((C,), math.log(0.5), dtype=DTYPE)
        self._hyper_mean = torch.zeros(C, 2, dtype=DTYPE)
        self._hyper_m2 = torch.zeros(C, 2, 2, dtype=DTYPE)
        self._hyper_n = 0
        self._chol = torch.eye(2, dtype=DTYPE).expand(C, 2, 2).clone()
        self._accept_sum = {"c": 0.0, "theta": 0.0, "hyper": 0.0}
        self._accept_last = dict(self._accept_sum)
        self._class_moves = max(int((labels < 0).sum()) * (self.num_chains // labels.shape[0]), 1)
        self._label_counts = torch.zeros(C, obs.shape[-2], num_classes, dtype=DTYPE)

    def _initial_state(self, num_obs: int, num_classes: int) -> MHState:
        C, g, hp = self.num_chains, self._gen, self.hyperprior
        kappa = gamma_variates(torch.full((C,), hp.beta), hp.eta, g).clamp(0.05, 50)
        gamma = gamma_variates(torch.full((C,), hp.nu), hp.omega, g).clamp(0.05, 500)
        theta = gamma_variates(kappa.unsqueeze(-1).expand(C, num_classes), gamma.unsqueeze(-1), g)
        labels = self._data.labels.expand(C, num_obs)
        cdf = self._data.proposal_cdf.expand(C, num_obs, num_classes)
        u = torch.rand(C, num_obs, 1, generator=g, dtype=DTYPE) * cdf[..., -1:]
        c0 = (u > cdf).sum(-1).clamp_max(num_classes - 1)
        return MHState(
            torch.where(labels >= 0, labels, c0),
            theta.clamp(0.1, 1000).log(),
            kappa.log(),
            gamma.log(),
        )

    @property
    def initial_params(self) -> dict[str, Tensor]:
        return self._params()

    @initial_params.setter
    def initial_params(self, params: dict[str, Tensor]) -> None:
        raise NotImplementedError("HBNIMetropolis draws its own initial state from the hyperprior (set `seed`)")

    def _params(self) -> dict[str, Tensor]:
        s = self._state
        return {"theta": s.log_theta.exp(), "kappa": s.log_kappa.exp(), "gamma": s.log_gamma.exp()}

    def sample(self, params: dict[str, Tensor]) -> dict[str, Tensor]:
        """Advance every chain by one iteration and return the new ``theta``, ``kappa``, ``gamma``."""
        s, g = self._state, self._gen
        c, acc_c = update_classes(s, self._data, self.stay_prob, g)
        s = s._replace(c=c)
        log_theta, acc_t = update_theta(s, self._data, self._log_step_theta.exp(), g)
        s = s._replace(log_theta=log_theta)
        log_kappa, log_gamma, acc_h = update_hyper(s, self.hyperprior, self._chol, g)
        s = s._replace(log_kappa=log_kappa, log_gamma=log_gamma)
        self._state = s
        warm = self._t < self._warmup_steps
        if warm:
            self._adapt(acc_t, acc_h)
        else:
            self._label_counts += torch.nn.functional.one_hot(s.c, self._label_counts.shape[-1]).to(DTYPE)
        self._accept_last = {
            "c": float(acc_c.sum()) / self._class_moves,
            "theta": float(acc_t.to(DTYPE).mean()),
            "hyper": float(acc_h.to(DTYPE).mean()),
        }
        if not warm:
            for k, v in self._accept_last.items():
                self._accept_sum[k] += v
        self._t += 1
        return self._params()

    def _adapt(self, acc_theta: Tensor, acc_hyper: Tensor) -> None:
        rate = (self._t + 1) ** -0.6
        self._log_step_theta += rate * (acc_theta.to(DTYPE) - _TARGET_1D)
        self._log_scale_hyper += rate * (acc_hyper.to(DTYPE) - _TARGET_2D)
        if self._t >= self._warmup_steps // 4:
            x = torch.stack([self._state.log_kappa, self._state.log_gamma], -1)
            self._hyper_n += 1
            delta = x - self._hyper_mean
            self._hyper_mean += delta / self._hyper_n
            self._hyper_m2 += delta.unsqueeze(-1) * (x - self._hyper_mean).unsqueeze(-2)
        chol = torch.eye(2, dtype=DTYPE).expand(self.num_chains, 2, 2)
        if self._hyper_n >= 20:
            chol = _cholesky_2x2(self._hyper_m2 / (self._hyper_n - 1) + 1e-4 * torch.eye(2, dtype=DTYPE))
        self._chol = self._log_scale_hyper.exp()[:, None, None] * chol

    @property
    def label_probs(self) -> Tensor:
        """``(C, N, M)`` post-warm-up frequency of each class for each output, per chain."""
        draws = max(self._t - self._warmup_steps, 1)
        return self._label_counts / draws

    def logging(self) -> dict[str, str]:
        return {f"acc. {k}": f"{v:.2f}" for k, v in self._accept_last.items()}

    def diagnostics(self) -> dict:
        draws = max(self._t - self._warmup_steps, 1)
        return {
            "divergences": [],
            "acceptance rate": {k: v / draws for k, v in self._accept_sum.items()},
            "step size theta": self._log_step_theta.exp().mean(0).tolist(),
            "step scale hyper": float(self._log_scale_hyper.exp().mean()),
        }



def _cholesky_2x2(cov: Tensor) -> Tensor:
    """Closed-form lower Cholesky factor of a batch of SPD 2x2 matrices ``(..., 2, 2)``."""
    l11 = cov[..., 0, 0].sqrt()
    l21 = cov[..., 1, 0] / l11
    l22 = (cov[..., 1, 1] - l21 * l21).sqrt()
    zero = torch.zeros_like(l11)
    return torch.stack([torch.stack([l11, zero], -1), torch.stack([l21, l22], -1)], -2)
