"""Classifier outputs drawn from the paper's model with an explicit ``torch.Generator``.

``o | c = m ~ Dir(theta_m e_m + 1)`` is drawn as normalised independent gammas: ``x_m ~ Ga(theta_m + 1, 1)`` and
``x_j ~ Ga(1, 1) = Exp(1)`` for ``j != m`` (:mod:`hbni_pyro.distributions.sampling`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.sampling import as_classes, as_params, check_values, gamma_variates, sample_gamma
from hbni_pyro.validation import DTYPE, has_values
from hbni_infra.checks import as_generator


def sample_outputs(theta: Tensor, classes: Tensor, generator: torch.Generator) -> Tensor:
    """Draw one classifier output per entry of ``classes``.

    Args:
        theta: ``(M,)`` noise parameters, or ``(..., M)`` broadcasting against ``classes``
            (one theta vector per draw, e.g. posterior draws); finite and ``> -1`` (the Dirichlet's lifted
            concentration ``theta_m + 1`` is positive).
        classes: integer tensor of true classes in ``[0, M)``, any shape ``S``.
        generator: the source of randomness, a ``torch.Generator`` on ``theta``'s device.

    Returns:
        float64 ``(*S, M)`` outputs on the simplex (entries floored at the smallest positive double).

    Raises:
        TypeError: non-numeric ``theta``, non-integer ``classes``, or no ``torch.Generator``.
        ValueError: ``theta`` NaN, infinite or ``<= -1``; a class outside ``[0, M)``.
    """
    theta = as_params("theta", theta)
    if theta.dim() == 0 or theta.shape[-1] < 2:
        raise ValueError(f"theta: expected shape (..., M) with M >= 2 classes, got {tuple(theta.shape)}")
    check_values("theta", theta, -1.0, False, "the Dirichlet concentration theta + 1 must be positive")
    num_classes = theta.shape[-1]
    classes = as_classes(classes, num_classes, theta.device)
    generator = as_generator("generator", generator, theta.device)
    one_hot = torch.nn.functional.one_hot(classes, num_classes).to(DTYPE)
    lifted = (theta * one_hot).sum(-1)
    e = torch.rand(one_hot.shape, generator=generator, dtype=DTYPE, device=theta.device).clamp_min(1e-300)
    x = -e.log()
    if has_values(lifted) and bool((lifted < 0).any()):  # shapes below 1: the boost (same draws otherwise)
        g = gamma_variates(lifted + 1.0, 1.0, generator)
    else:
        g = sample_gamma(lifted + 1.0, generator)
    x = torch.where(one_hot.bool(), g.unsqueeze(-1), x)
    x = x.clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)
