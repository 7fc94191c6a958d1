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

import numpy as np
import torch
from torch import Tensor

from hbni_pyro.density import lifted_normaliser
from hbni_pyro.generative import gamma_variates
from hbni_pyro.kernels.base import (
    AdaptiveWalk,
    AdaptiveWalk2D,
    BatchedKernel,
    flatten_chains,
    fraction,
)
from hbni_pyro.kernels.class_move_numba import class_move_stats
from hbni_pyro.kernels.mh_steps import (
    MHState,
    frame_data,
    sufficient_stats,
    update_classes,
    update_hyper,
    update_theta,
)
from hbni_pyro.model import HyperPrior
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float


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
        from the proposal weights instead put 3 in 4 outputs of the 200 000 x 10 benchmark data in a wrong class (the
        largest entry: 1 in 9), and a chain whose first ``theta`` was small then drifted to a state of near-uniform
        classes and ``theta`` near 0 that it did not leave: a tiny share of the posterior, yet one of 4 chains of a
        200 000 x 10 unlabelled fit and one of 16 of a 20 000 x 10 fit settled there (split R-hat of ``theta`` 181
        and 26)."""
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


class HBNIMetropolis(BatchedKernel):
    """Vectorised MH kernel for the HBNI posterior ``p(c, theta, kappa, gamma | obs)``.

    Args:
        num_chains, hyperprior, class_prior, seed: see :class:`~hbni_pyro.kernels.base.BatchedKernel`.
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
