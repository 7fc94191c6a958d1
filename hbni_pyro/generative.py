"""Sampling classifier outputs from the HBNI generative model with an explicit torch.Generator.

``o | c = m ~ Dir(theta_m e_m + 1)`` is drawn as normalised independent gammas:
``x_m ~ Ga(theta_m + 1, 1)`` and ``x_j ~ Ga(1, 1) = Exp(1)`` for ``j != m``. Gamma draws
with shape >= 1 use Marsaglia and Tsang's squeeze method, vectorised over all entries,
so every draw is reproducible from the generator alone.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.validation import DTYPE


def sample_gamma(shape: Tensor, generator: torch.Generator) -> Tensor:
    """Draw ``Ga(shape, 1)`` for every entry of ``shape`` (all entries must be >= 1)."""
    d = shape - 1.0 / 3.0
    c = 1.0 / torch.sqrt(9.0 * d)
    out = torch.empty_like(shape)
    todo = torch.ones_like(shape, dtype=torch.bool)
    while todo.any():
        idx = todo.nonzero(as_tuple=True)
        dd, cc = d[idx], c[idx]
        x = torch.randn(dd.shape, generator=generator, dtype=shape.dtype)
        u = torch.rand(dd.shape, generator=generator, dtype=shape.dtype)
        v = (1 + cc * x) ** 3
        ok = (v > 0) & (u.log() < 0.5 * x * x + dd - dd * v + dd * v.clamp_min(1e-300).log())
        out[tuple(i[ok] for i in idx)] = (dd * v)[ok]
        todo[tuple(i[ok] for i in idx)] = False
    return out


def gamma_variates(shape: Tensor, scale: Tensor | float, generator: torch.Generator) -> Tensor:
    """Draw ``Ga(shape, scale)`` (shape-scale) for every entry; any ``shape > 0``.

    Shapes below 1 use the boost ``Ga(a) = Ga(a + 1) * U ** (1 / a)``.
    """
    shape = torch.as_tensor(shape, dtype=DTYPE)
    small = shape < 1
    x = sample_gamma(torch.where(small, shape + 1, shape), generator)
    u = torch.rand(shape.shape, generator=generator, dtype=DTYPE)
    return torch.where(small, x * u ** (1 / shape), x) * scale


def sample_outputs(theta: Tensor, classes: Tensor, generator: torch.Generator) -> Tensor:
    """Draw one classifier output per entry of ``classes``.

    Args:
        theta: ``(M,)`` noise parameters, or ``(..., M)`` broadcasting against ``classes``
            (one theta vector per draw, e.g. posterior draws).
        classes: integer tensor of true classes in ``[0, M)``, any shape ``S``.
        generator: the source of randomness.

    Returns:
        float64 ``(*S, M)`` outputs on the simplex (entries floored at the smallest positive double).
    """
    theta = torch.as_tensor(theta, dtype=DTYPE)
    classes = torch.as_tensor(classes, dtype=torch.long)
    num_classes = theta.shape[-1]
    one_hot = torch.nn.functional.one_hot(classes, num_classes).to(DTYPE)
    lifted = (theta * one_hot).sum(-1)
    e = torch.rand(one_hot.shape, generator=generator, dtype=DTYPE).clamp_min(1e-300)
    x = -e.log()
    g = sample_gamma(lifted + 1.0, generator)
    x = torch.where(one_hot.bool(), g.unsqueeze(-1), x)
    x = x.clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)
