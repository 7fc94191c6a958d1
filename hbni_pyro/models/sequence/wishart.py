"""Wishart and inverse-Wishart densities, seeded sampling, and Pyro distributions over their Cholesky factors.

Used by the sequence-aware noise model, whose covariances carry (inverse-)Wishart priors:
conjugate, so its MH kernel draws them from their exact conditionals, and, written over
Cholesky factors (support ``lower_cholesky``, which has a bijection to unconstrained space),
sampled by NUTS in its Pyro reference model.

Conventions (``d x d`` matrices, ``df > d - 1``):

- ``Wishart(X; df, V)``: scale ``V``, mean ``df * V``;
  ``log p = (df - d - 1)/2 log|X| - tr(V^-1 X)/2 - df d/2 log 2 - df/2 log|V| - lmvgamma_d(df/2)``.
- ``InvWishart(S; df, Psi)``: ``S^-1 ~ Wishart(df, Psi^-1)``, mean ``Psi / (df - d - 1)``;
  ``log p = df/2 log|Psi| - df d/2 log 2 - lmvgamma_d(df/2) - (df + d + 1)/2 log|S| - tr(Psi S^-1)/2``.
"""

from __future__ import annotations

import math

import torch
from pyro.distributions.torch_distribution import TorchDistribution
from torch import Tensor
from torch.distributions import biject_to, constraints, transform_to
from torch.distributions.transforms import Transform

from hbni_pyro.distributions.sampling import gamma_variates


def logdet_spd(x: Tensor) -> Tensor:
    """``log|X|`` of symmetric positive-definite matrices ``(..., d, d)`` through their Cholesky factor."""
    return 2 * torch.linalg.cholesky(x).diagonal(dim1=-2, dim2=-1).log().sum(-1)


def wishart_log_prob(x: Tensor, df: Tensor | float, scale_inv: Tensor, logdet_scale: Tensor) -> Tensor:
    """``log Wishart(X; df, V)`` given ``V^-1`` and ``log|V|`` (so a conditional update need not invert V)."""
    d = x.shape[-1]
    df = torch.as_tensor(df, dtype=x.dtype)
    return (
        0.5 * (df - d - 1) * logdet_spd(x)
        - 0.5 * (scale_inv * x).sum((-1, -2))
        - 0.5 * df * d * math.log(2)
        - 0.5 * df * logdet_scale
        - torch.mvlgamma(0.5 * df, d)
    )


def inv_wishart_log_prob(prec: Tensor, df: Tensor | float, psi: Tensor) -> Tensor:
    """``log InvWishart(S; df, Psi)`` of ``S = prec^-1``, given the precision ``prec`` (density over ``S``)."""
    d = prec.shape[-1]
    df = torch.as_tensor(df, dtype=prec.dtype)
    return (
        0.5 * df * logdet_spd(psi)
        - 0.5 * df * d * math.log(2)
        - torch.mvlgamma(0.5 * df, d)
        + 0.5 * (df + d + 1) * logdet_spd(prec)
        - 0.5 * (psi * prec).sum((-1, -2))
    )


def sample_wishart(df: Tensor, scale_tril: Tensor, generator: torch.Generator) -> Tensor:
    """Draw ``Wishart(df, L L^T)`` by Bartlett's decomposition, vectorised over the batch.

    Args:
        df: ``(...)`` degrees of freedom (> d - 1).
        scale_tril: ``(..., d, d)`` lower Cholesky factor ``L`` of the scale.
        generator: the only source of randomness, on ``scale_tril``'s device.

    Returns:
        ``(..., d, d)`` draws ``L A A^T L^T`` with ``A`` lower triangular, ``A_ii^2 ~ chi2(df - i)``
        (``i = 0..d-1``) and standard normal entries below the diagonal.
    """
    d = scale_tril.shape[-1]
    batch = scale_tril.shape[:-2]
    like = dict(dtype=scale_tril.dtype, device=scale_tril.device)
    df = torch.as_tensor(df, **like).expand(batch)
    shapes = 0.5 * (df.unsqueeze(-1) - torch.arange(d, **like))
    diag = (2 * gamma_variates(shapes, 1.0, generator)).sqrt()
    normal = torch.randn(batch + (d, d), generator=generator, **like).tril(-1)
    a = normal + torch.diag_embed(diag)
    la = scale_tril @ a
    return la @ la.transpose(-1, -2)


def _tril_log_jacobian(tril: Tensor) -> Tensor:
    """``log |d(L L^T) / dL|`` for lower-triangular ``L`` with positive diagonal: ``d log 2 + sum_i (d - i) log L_ii``."""
    d = tril.shape[-1]
    powers = torch.arange(d, 0, -1, dtype=tril.dtype, device=tril.device)
    return d * math.log(2) + (powers * tril.diagonal(dim1=-2, dim2=-1).log()).sum(-1)


class _CholeskyFactor(constraints._LowerCholesky):
    """Lower-triangular matrices with a positive diagonal, with a registered bijection for NUTS."""


cholesky_factor = _CholeskyFactor()


class CholeskyFactorTransform(Transform):
    """Bijection from ``d (d + 1) / 2`` unconstrained reals to a lower Cholesky factor ``(d, d)``:
    the reals fill the lower triangle row by row, and the diagonal is exponentiated."""

    domain = constraints.real_vector
    codomain = cholesky_factor
    bijective = True

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CholeskyFactorTransform)

    @staticmethod
    def _size(n: int) -> int:
        return int(round((math.sqrt(8 * n + 1) - 1) / 2))

    def _call(self, x: Tensor) -> Tensor:
        d = self._size(x.shape[-1])
        rows, cols = torch.tril_indices(d, d)
        out = x.new_zeros(x.shape[:-1] + (d, d))
        out[..., rows, cols] = torch.where(rows == cols, x.exp(), x)
        return out

    def _inverse(self, y: Tensor) -> Tensor:
        d = y.shape[-1]
        rows, cols = torch.tril_indices(d, d)
        v = y[..., rows, cols]
        return torch.where(rows == cols, v.log(), v)

    def log_abs_det_jacobian(self, x: Tensor, y: Tensor) -> Tensor:
        return y.diagonal(dim1=-2, dim2=-1).log().sum(-1)

    def forward_shape(self, shape):
        d = self._size(shape[-1])
        return torch.Size(shape[:-1]) + (d, d)

    def inverse_shape(self, shape):
        d = shape[-1]
        return torch.Size(shape[:-2]) + (d * (d + 1) // 2,)


biject_to.register(_CholeskyFactor)(lambda constraint: CholeskyFactorTransform())
transform_to.register(_CholeskyFactor)(lambda constraint: CholeskyFactorTransform())


class WishartCholesky(TorchDistribution):
    """The Cholesky factor ``L`` of ``X = L L^T ~ Wishart(df, V)``: ``log p(L) = log Wishart(L L^T) + log|dX/dL|``.

    Args:
        df: ``(...)`` degrees of freedom; scale: ``(..., d, d)`` the scale ``V``.
    """

    arg_constraints = {"df": constraints.positive, "scale": constraints.positive_definite}
    support = cholesky_factor

    def __init__(self, df: Tensor, scale: Tensor, validate_args: bool | None = None) -> None:
        batch = torch.broadcast_shapes(torch.as_tensor(df).shape, scale.shape[:-2])
        self.df = torch.as_tensor(df, dtype=scale.dtype).expand(batch)
        self.scale = scale.expand(batch + scale.shape[-2:])
        super().__init__(batch, scale.shape[-2:], validate_args=validate_args)

    def expand(self, batch_shape, _instance=None):
        batch_shape = torch.Size(batch_shape)
        return type(self)(self.df.expand(batch_shape), self.scale.expand(batch_shape + self.event_shape))

    def sample(self, sample_shape=torch.Size()) -> Tensor:
        shape = torch.Size(sample_shape) + self.batch_shape
        x = torch.distributions.Wishart(
            self.df.expand(shape), covariance_matrix=self.scale.expand(shape + self.event_shape)
        ).sample()
        return torch.linalg.cholesky(x)

    def log_prob(self, value: Tensor) -> Tensor:
        x = value @ value.transpose(-1, -2)
        scale_inv = torch.linalg.inv(self.scale)
        return wishart_log_prob(x, self.df, scale_inv, logdet_spd(self.scale)) + _tril_log_jacobian(value)


class InvWishartCholesky(WishartCholesky):
    """The Cholesky factor ``L`` of ``S = L L^T ~ InvWishart(df, Psi)`` (``scale`` is ``Psi``)."""

    def sample(self, sample_shape=torch.Size()) -> Tensor:
        shape = torch.Size(sample_shape) + self.batch_shape
        psi_inv = torch.linalg.inv(self.scale).expand(shape + self.event_shape)
        prec = torch.distributions.Wishart(self.df.expand(shape), covariance_matrix=psi_inv).sample()
        return torch.linalg.cholesky(torch.linalg.inv(prec))

    def log_prob(self, value: Tensor) -> Tensor:
        prec = torch.cholesky_inverse(value)
        return inv_wishart_log_prob(prec, self.df, self.scale) + _tril_log_jacobian(value)
