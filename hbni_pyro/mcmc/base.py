"""What every HBNI kernel shares: the ``pyro.infer.MCMC`` protocol, the datasets x chains layout,
step-size adaptation in warm-up, acceptance bookkeeping and posterior label frequencies.

A kernel advances ``num_chains`` chains in one tensor program; ``pyro.infer.MCMC`` runs it
as a single "chain" whose sites carry a leading chain dimension. The data may be one dataset
``(N, M)`` shared by every chain or ``D`` same-sized datasets ``(D, N, M)``, each fitted by
``num_chains / D`` chains (datasets-major order). Inside, state tensors are ``(D, Cp, ...)``
and data ``(D, 1, ...)``, so one broadcast serves both layouts.

A kernel runs on the device of its data: its state, step sizes, label counts and its
``torch.Generator`` are created there. Acceptance counts stay there too, as 0-d tensors, and are
read to the host once per iteration for the progress log (:meth:`BatchedKernel.logging`).
"""

from __future__ import annotations

import math

import torch
from pyro.infer.mcmc.mcmc_kernel import MCMCKernel
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_int
from hbni_infra.streams import torch_generator


def rm_rate(t: int) -> float:
    """Robbins-Monro gain ``(t + 1)^-0.6`` of warm-up iteration ``t``."""
    return (t + 1) ** -0.6


class AdaptiveWalk:
    """Per-coordinate Gaussian random-walk scales on a log scale, tuned in warm-up towards ``target``."""

    def __init__(
        self, shape: tuple[int, ...], target: float, init: float = 0.5, device: torch.device | str = "cpu"
    ) -> None:
        self.log_step = torch.full(shape, math.log(init), dtype=DTYPE, device=device)
        self.target = target

    @property
    def step(self) -> Tensor:
        return self.log_step.exp()

    def adapt(self, accepted: Tensor, t: int) -> None:
        self.log_step += rm_rate(t) * (accepted.to(DTYPE) - self.target)


class AdaptiveWalk2D:
    """A joint 2-D random walk whose covariance is learnt from each chain's own warm-up draws
    (after a quarter of warm-up), scaled towards acceptance ``target``."""

    def __init__(self, batch: tuple[int, ...], target: float = 0.35, device: torch.device | str = "cpu") -> None:
        self.log_scale = torch.full(batch, math.log(0.5), dtype=DTYPE, device=device)
        self.mean = torch.zeros(batch + (2,), dtype=DTYPE, device=device)
        self.m2 = torch.zeros(batch + (2, 2), dtype=DTYPE, device=device)
        self.n = 0
        self.eye = torch.eye(2, dtype=DTYPE, device=device)
        self.chol = self.eye.expand(batch + (2, 2)).clone()
        self.target = target

    def adapt(self, x: Tensor, accepted: Tensor, t: int, warmup_steps: int) -> None:
        self.log_scale += rm_rate(t) * (accepted.to(DTYPE) - self.target)
        if t >= warmup_steps // 4:
            self.n += 1
            delta = x - self.mean
            self.mean += delta / self.n
            self.m2 += delta.unsqueeze(-1) * (x - self.mean).unsqueeze(-2)
        chol = self.eye.expand(self.chol.shape)
        if self.n >= 20:
            chol = cholesky_2x2(self.m2 / (self.n - 1) + 1e-4 * self.eye)
        self.chol = self.log_scale.exp()[..., None, None] * chol


def cholesky_2x2(cov: Tensor) -> Tensor:
    """Closed-form lower Cholesky factor of a batch of SPD 2x2 matrices ``(..., 2, 2)``."""
    l11 = cov[..., 0, 0].sqrt()
    l21 = cov[..., 1, 0] / l11
    l22 = (cov[..., 1, 1] - l21 * l21).sqrt()
    zero = torch.zeros_like(l11)
    return torch.stack([torch.stack([l11, zero], -1), torch.stack([l21, l22], -1)], -2)


class BatchedKernel(MCMCKernel):
    """Base of the HBNI kernels. Subclasses define ``_setup_state``, ``_step`` and ``_params``.

    Args:
        num_chains: chains advanced together (a multiple of the number of datasets).
        hyperprior: the :class:`~hbni_pyro.HyperPrior`.
        class_prior: ``(M,)`` class prior ``p`` (``None`` = uniform).
        seed: seed of the kernel's own ``torch.Generator`` (initial state and every move).
    """

    transforms: dict = {}
    moves: tuple[str, ...] = ()
    """Names of the kernel's moves, in the order of its acceptance rates."""

    def __init__(
        self,
        num_chains: int = 16,
        hyperprior: HyperPrior = HyperPrior(),
        class_prior: Tensor | None = None,
        seed: int = 0,
    ) -> None:
        num_chains = as_int("num_chains", num_chains, minimum=1)
        if not isinstance(hyperprior, HyperPrior):
            raise TypeError(f"hyperprior: expected a HyperPrior, got {type(hyperprior).__name__}")
        self.num_chains = num_chains
        self.hyperprior = hyperprior
        self.class_prior = class_prior
        self.seed = seed

    def _begin(self, warmup_steps: int, num_datasets: int, num_classes: int, device: torch.device) -> None:
        """Start a run on ``device`` (the data's): generator, counters, layout ``(D, Cp)`` and the class prior."""
        if self.num_chains % num_datasets:
            raise ValueError(f"num_chains: expected a multiple of the {num_datasets} datasets, got {self.num_chains}")
        self.device = device
        self.batch = (num_datasets, self.num_chains // num_datasets)
        prior = self.class_prior if self.class_prior is not None else torch.full((num_classes,), 1.0 / num_classes)
        self.log_prior = prior.to(device, DTYPE).log()
        self._warmup_steps = warmup_steps
        self._t = 0
        self._gen = torch_generator(self.seed, device)
        self._accept_sum = {k: torch.zeros((), dtype=DTYPE, device=device) for k in self.moves}
        self._accept_last = dict(self._accept_sum)

    @property
    def initial_params(self) -> dict[str, Tensor]:
        return self._params()

    @initial_params.setter
    def initial_params(self, params: dict[str, Tensor]) -> None:
        raise NotImplementedError(f"{type(self).__name__} draws its own initial state from the prior (set `seed`)")

    def _params(self) -> dict[str, Tensor]:
        """Current sites, each flattened to ``(num_chains, ...)``."""
        raise NotImplementedError

    def _step(self, warm: bool) -> dict[str, Tensor]:
        """Advance every chain one iteration (adapting step sizes if ``warm``); return acceptance rates (0-d)."""
        raise NotImplementedError

    def sample(self, params: dict[str, Tensor]) -> dict[str, Tensor]:
        """Advance every chain by one iteration and return the new sites."""
        warm = self._t < self._warmup_steps
        self._accept_last = self._step(warm)
        if not warm:
            for k, v in self._accept_last.items():
                self._accept_sum[k] = self._accept_sum[k] + v
        self._t += 1
        return self._params()

    @property
    def draws_done(self) -> int:
        return max(self._t - self._warmup_steps, 1)

    def logging(self) -> dict[str, str]:
        rates = torch.stack(list(self._accept_last.values())).tolist()  # one host sync for every move
        return {f"acc. {k}": f"{v:.2f}" for k, v in zip(self._accept_last, rates)}

    def diagnostics(self) -> dict:
        sums = torch.stack(list(self._accept_sum.values())).tolist()
        return {"divergences": [], "acceptance rate": {k: v / self.draws_done for k, v in zip(self._accept_sum, sums)}}


def flatten_chains(x: Tensor) -> Tensor:
    """``(D, Cp, ...)`` -> ``(D * Cp, ...)``."""
    return x.reshape((-1,) + x.shape[2:])


def fraction(accepted: Tensor, moves: int | None = None) -> Tensor:
    """Share of accepted moves, a float64 0-d tensor on ``accepted``'s device: ``accepted.sum() / moves``
    (``None``: over all elements)."""
    return accepted.sum().to(DTYPE) / (accepted.numel() if moves is None else max(moves, 1))
