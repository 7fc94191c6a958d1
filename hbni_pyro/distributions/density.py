"""Closed-form log densities of the HBNI noise models: the one implementation of their likelihood terms.

Every noise model here draws an output ``o`` of a class-``c`` object from a Dirichlet with
concentrations ``alpha_c`` (M values). Over a block of ``n`` outputs with ``s = sum_i log o_i``
(an ``(M,)`` vector) the log likelihood depends on the outputs only through ``(n, s)``:

    sum_i log Dir(o_i; alpha_c) = n * (lgamma(sum_j alpha_cj) - sum_j lgamma(alpha_cj))
                                  + sum_j (alpha_cj - 1) * s_j                       (*)

That one formula is used by the Pyro models (through :class:`DirichletOutputs`), the MH
kernels (per-class sufficient statistics of the outputs assigned to each class), the filters
(a stream's running sum of log outputs) and the sequence model (per-sequence sums).

- The **paper's** model lifts only the true class: ``alpha_c = theta_c e_c + 1``. Then (*) is
  ``n * (lgamma(M + theta_c) - lgamma(1 + theta_c)) + theta_c * s_c`` (the other
  concentrations are 1: their ``(alpha - 1) s`` terms vanish and ``lgamma(1) = 0``).
- The **confusion-aware** model has ``alpha_c = theta_c e_c + beta_c`` with ``beta_cc = 1`` and
  free off-diagonal ``beta_cj > 0``: every class has its own pattern of confusions. All
  ``beta_cj = 1`` is the paper's model.

Gamma densities use the **shape-scale** form throughout this package:
``log Ga(x; k, s) = (k - 1) log x - x / s - lgamma(k) - k log s``. Pyro's
``Gamma(concentration, rate)`` is shape-rate, so ``rate = 1 / scale``.
"""

from __future__ import annotations

import math

import pyro.distributions as dist
import torch
from pyro.distributions.torch_distribution import TorchDistribution
from torch import Tensor
from torch.distributions import constraints


def lifted_normaliser(theta: Tensor, num_classes: int) -> Tensor:
    """``lgamma(M + theta) - lgamma(1 + theta)``: the log normaliser of ``Dir(theta e_m + 1)`` (elementwise)."""
    return torch.lgamma(num_classes + theta) - torch.lgamma(1 + theta)


def lifted_block_log_prob(count: Tensor | float, sum_log_own: Tensor, theta: Tensor, num_classes: int) -> Tensor:
    """(*) for the paper's model: ``count * (lgamma(M + theta) - lgamma(1 + theta)) + theta * sum_log_own``.

    Args:
        count: number of outputs in the block (broadcasts).
        sum_log_own: ``sum_i log o_i,m`` of each class hypothesis ``m``'s own entry, ``(..., M)``.
        theta: ``(..., M)`` noise levels; broadcasts against ``sum_log_own``.
        num_classes: ``M``.
    """
    return count * lifted_normaliser(theta, num_classes) + theta * sum_log_own


def lifted_dirichlet_log_prob(obs: Tensor, theta: Tensor) -> Tensor:
    """Log density of each output under every class hypothesis of the paper's model.

    Args:
        obs: ``(..., M)`` outputs on the simplex with strictly positive entries
            (see :func:`hbni_pyro.validation.as_outputs`).
        theta: ``(..., M)`` noise parameters ``theta_m > 0``; broadcasts against ``obs``.

    Returns:
        ``(..., M)`` tensor whose entry ``m`` is ``log Dir(o; theta_m e_m + 1)``.
    """
    return lifted_block_log_prob(1.0, obs.log(), theta, obs.shape[-1])


def concentrations(theta: Tensor, beta: Tensor | None = None) -> Tensor:
    """Concentration matrix ``alpha (..., M, M)``, row ``c`` = ``theta_c e_c + beta_c`` (``beta_cc = 1``).

    Args:
        theta: ``(..., M)`` lifts of the true class.
        beta: ``(..., M, M)`` off-diagonal concentrations (the diagonal is ignored), or ``None``
            for the paper's model (all 1).
    """
    num_classes = theta.shape[-1]
    eye = torch.eye(num_classes, dtype=theta.dtype, device=theta.device)
    base = torch.ones_like(eye) if beta is None else beta * (1 - eye) + eye
    return base + theta.unsqueeze(-1) * eye


def dirichlet_normaliser(alpha: Tensor) -> Tensor:
    """``lgamma(sum_j alpha_j) - sum_j lgamma(alpha_j)`` over the last dim."""
    return torch.lgamma(alpha.sum(-1)) - torch.lgamma(alpha).sum(-1)


def dirichlet_block_log_prob(count: Tensor | float, sum_log: Tensor, alpha: Tensor) -> Tensor:
    """(*): ``count * normaliser(alpha) + sum_j (alpha_j - 1) * sum_log_j``.

    Args:
        count: number of outputs in the block (broadcasts against the result).
        sum_log: ``(..., M)`` sum of the block's log outputs.
        alpha: ``(..., M)`` concentrations; broadcasts against ``sum_log``.

    Returns:
        ``(...)`` log likelihood of the block.
    """
    return count * dirichlet_normaliser(alpha) + ((alpha - 1) * sum_log).sum(-1)


def class_log_lik(count: Tensor | float, sum_log: Tensor, theta: Tensor, beta: Tensor | None = None) -> Tensor:
    """(*) for ``K`` blocks of outputs, each under every class hypothesis.

    Args:
        count: outputs per block, ``(..., K)`` or a float (1 for single outputs).
        sum_log: ``(..., K, M)`` sum of each block's log outputs.
        theta: ``(..., M)``; beta: ``(..., M, M)`` or ``None`` (the paper's model); batch dims
            broadcast against those of ``sum_log``.

    Returns:
        ``(..., K, M)``: entry ``[k, c]`` is ``log prod_{i in block k} Dir(o_i; alpha_c)``.
    """
    count = torch.as_tensor(count, dtype=sum_log.dtype)
    count = count.unsqueeze(-1) if count.dim() else count
    if beta is None:
        return lifted_block_log_prob(count, sum_log, theta.unsqueeze(-2), theta.shape[-1])
    return block_log_lik(count, sum_log, *dirichlet_terms(concentrations(theta, beta)))


def dirichlet_terms(alpha: Tensor) -> tuple[Tensor, Tensor]:
    """The two parameter terms of (*) for concentration rows ``alpha (..., M, M)``: the normalisers
    ``(..., M)`` and the exponents ``alpha - 1`` ``(..., M, M)`` (computed once, reused for every block)."""
    return dirichlet_normaliser(alpha), alpha - 1


def block_log_lik(count: Tensor, sum_log: Tensor, normaliser: Tensor, exponent: Tensor) -> Tensor:
    """(*) from :func:`dirichlet_terms` for ``K`` blocks under ``C`` concentration rows (e.g. classes,
    or draws x classes flattened): ``count (..., K, 1)``, ``sum_log (..., K, M)``, ``normaliser (..., C)``,
    ``exponent (..., C, M)`` -> ``(..., K, C)``."""
    return count * normaliser.unsqueeze(-2) + sum_log @ exponent.transpose(-1, -2)


def assigned_log_lik(counts: Tensor, sums: Tensor, theta: Tensor, beta: Tensor | None = None) -> Tensor:
    """(*) for each class's own outputs, from per-class sufficient statistics.

    Args:
        counts: ``(..., M)`` outputs assigned to each class.
        sums: ``(..., M, M)``: row ``c`` is the sum of the log outputs assigned to class ``c``.
        theta, beta: as in :func:`class_log_lik`.

    Returns:
        ``(..., M)``: entry ``c`` is ``log prod_{i: c_i = c} Dir(o_i; alpha_c)``.
    """
    if beta is None:
        return lifted_block_log_prob(counts, sums.diagonal(dim1=-2, dim2=-1), theta, theta.shape[-1])
    alpha = concentrations(theta, beta)
    return counts * dirichlet_normaliser(alpha) + ((alpha - 1) * sums).sum(-1)


def gamma_log_prob(x: Tensor, shape: Tensor | float, scale: Tensor | float) -> Tensor:
    """``log Ga(x; shape, scale)`` in shape-scale form (mean ``shape * scale``)."""
    shape = torch.as_tensor(shape, dtype=x.dtype)
    scale = torch.as_tensor(scale, dtype=x.dtype)
    return (shape - 1) * x.log() - x / scale - torch.lgamma(shape) - shape * scale.log()


def normal_log_prob(x: Tensor, loc: Tensor | float, scale: Tensor | float) -> Tensor:
    """``log N(x; loc, scale**2)``."""
    scale = torch.as_tensor(scale, dtype=x.dtype)
    return -0.5 * ((x - loc) / scale) ** 2 - scale.log() - 0.5 * math.log(2 * math.pi)


class DirichletOutputs(TorchDistribution):
    """``Dir(alpha)`` whose ``log_prob`` is this module's closed form (*) with ``count = 1``.

    The Pyro models observe classifier outputs through it, so they share the likelihood terms
    of the kernels and filters; sampling delegates to :class:`pyro.distributions.Dirichlet`.

    Args:
        alpha: ``(..., M)`` concentrations (e.g. :func:`concentrations` indexed by each output's class).
    """

    arg_constraints = {"alpha": constraints.independent(constraints.positive, 1)}
    support = constraints.simplex

    def __init__(self, alpha: Tensor, validate_args: bool | None = None) -> None:
        self.alpha = alpha
        super().__init__(alpha.shape[:-1], alpha.shape[-1:], validate_args=validate_args)

    def expand(self, batch_shape, _instance=None):
        return DirichletOutputs(self.alpha.expand(torch.Size(batch_shape) + self.event_shape))

    def sample(self, sample_shape=torch.Size()) -> Tensor:
        return dist.Dirichlet(self.alpha).sample(sample_shape)

    def log_prob(self, value: Tensor) -> Tensor:
        return dirichlet_block_log_prob(1.0, value.log(), self.alpha)


def helmert_basis(
    num_classes: int, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
) -> Tensor:
    """Orthonormal ``(M - 1, M)`` basis of the simplex's tangent space (rows orthogonal to ``1``), on ``device``
    (``None``: the CPU).

    ``ilr(o) = helmert_basis(M) @ log o`` are the isometric log-ratio coordinates of an output.
    """
    basis = torch.zeros(num_classes - 1, num_classes, dtype=dtype)
    for i in range(1, num_classes):
        basis[i - 1, :i] = 1.0 / i
        basis[i - 1, i] = -1.0
        basis[i - 1] *= math.sqrt(i / (i + 1))
    return basis.to(device)


def ilr(obs: Tensor) -> Tensor:
    """Isometric log-ratio coordinates ``(..., M - 1)`` of strictly positive outputs ``(..., M)`` (on their device)."""
    return obs.log() @ helmert_basis(obs.shape[-1], obs.dtype, obs.device).T


def ilr_log_jacobian(obs: Tensor) -> Tensor:
    """``log |d ilr(o) / d o|`` over the simplex's ``M - 1`` free coordinates: ``-sum_m log o_m - log(M) / 2``.

    The density of an output is that of its coordinates plus this term (it involves no parameter).
    """
    return -obs.log().sum(-1) - 0.5 * math.log(obs.shape[-1])


class IlrNormalOutputs(TorchDistribution):
    """Outputs whose log-ratio coordinates are Gaussian: ``ilr(o) ~ N(loc, L L^T)`` (a logistic-normal).

    ``log_prob(o) = log N(ilr(o); loc, L L^T) + log |d ilr / d o|``; sampling maps a Gaussian
    draw back with ``o = softmax(H^T y)``.

    Args:
        loc: ``(..., d)``; scale_tril: ``(..., d, d)``; ``d = M - 1``.
    """

    arg_constraints = {"loc": constraints.real_vector, "scale_tril": constraints.lower_cholesky}
    support = constraints.simplex

    def __init__(self, loc: Tensor, scale_tril: Tensor, validate_args: bool | None = None) -> None:
        batch = torch.broadcast_shapes(loc.shape[:-1], scale_tril.shape[:-2])
        self.loc = loc.expand(batch + loc.shape[-1:])
        self.scale_tril = scale_tril.expand(batch + scale_tril.shape[-2:])
        super().__init__(batch, torch.Size([loc.shape[-1] + 1]), validate_args=validate_args)

    def expand(self, batch_shape, _instance=None):
        batch_shape = torch.Size(batch_shape)
        return IlrNormalOutputs(
            self.loc.expand(batch_shape + self.loc.shape[-1:]),
            self.scale_tril.expand(batch_shape + self.scale_tril.shape[-2:]),
        )

    def _gaussian(self) -> dist.MultivariateNormal:
        return dist.MultivariateNormal(self.loc, scale_tril=self.scale_tril)

    def sample(self, sample_shape=torch.Size()) -> Tensor:
        y = self._gaussian().sample(sample_shape)
        return torch.softmax(y @ helmert_basis(self.event_shape[0], y.dtype), -1)

    def log_prob(self, value: Tensor) -> Tensor:
        return self._gaussian().log_prob(ilr(value)) + ilr_log_jacobian(value)
