"""Closed-form log densities of the HBNI noise model.

The output model is ``o | c = m ~ Dir(theta_m * e_m + 1)``: only the m-th concentration
is lifted above 1. Its log density has the closed form

    log Dir(o; theta_m e_m + 1) = lgamma(M + theta_m) - lgamma(1 + theta_m) + theta_m * log o_m

(the other concentrations are 1, so their ``(alpha - 1) log o`` terms vanish and their
``lgamma(1)`` normalisers are 0).

Gamma densities use the **shape-scale** form throughout this package:
``log Ga(x; k, s) = (k - 1) log x - x / s - lgamma(k) - k log s``. Pyro's
``Gamma(concentration, rate)`` is shape-rate, so ``rate = 1 / scale``.
"""

from __future__ import annotations

import torch
from torch import Tensor


def lifted_dirichlet_log_prob(obs: Tensor, theta: Tensor) -> Tensor:
    """Log density of each output under every class hypothesis.

    Args:
        obs: ``(..., M)`` outputs on the simplex with strictly positive entries
            (see :func:`hbni_pyro.validation.as_outputs`).
        theta: ``(..., M)`` noise parameters ``theta_m > 0``; broadcasts against ``obs``.

    Returns:
        ``(..., M)`` tensor whose entry ``m`` is ``log Dir(o; theta_m e_m + 1)``.
    """
    num_classes = obs.shape[-1]
    return torch.lgamma(num_classes + theta) - torch.lgamma(1 + theta) + theta * obs.log()


def gamma_log_prob(x: Tensor, shape: Tensor | float, scale: Tensor | float) -> Tensor:
    """``log Ga(x; shape, scale)`` in shape-scale form (mean ``shape * scale``)."""
    shape = torch.as_tensor(shape, dtype=x.dtype)
    scale = torch.as_tensor(scale, dtype=x.dtype)
    return (shape - 1) * x.log() - x / scale - torch.lgamma(shape) - shape * scale.log()
