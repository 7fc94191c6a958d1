"""Sampling classifier outputs from the HBNI generative model with an explicit torch.Generator.

``o | c = m ~ Dir(theta_m e_m + 1)`` is drawn as normalised independent gammas:
``x_m ~ Ga(theta_m + 1, 1)`` and ``x_j ~ Ga(1, 1) = Exp(1)`` for ``j != m``. Gamma draws
with shape >= 1 use Marsaglia and Tsang's squeeze method, vectorised over all entries,
so every draw is reproducible from the generator alone. Draws are made on the device of the
parameters, with a generator of that device (:func:`hbni_infra.streams.torch_generator`). On ``meta`` parameters
(shapes only) there is no generator (``None``) and the draws are shapes without values.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.density import helmert_basis
from hbni_pyro.frame_correlation import ar1_normals
from hbni_pyro.validation import DTYPE, has_values


def sample_gamma(shape: Tensor, generator: torch.Generator | None) -> Tensor:
    """Draw ``Ga(shape, 1)`` for every entry of ``shape`` (all entries must be >= 1); shapes only on ``meta``."""
    if not has_values(shape):
        return torch.empty_like(shape)
    d = shape - 1.0 / 3.0
    c = 1.0 / torch.sqrt(9.0 * d)
    out = torch.empty_like(shape)
    todo = torch.ones_like(shape, dtype=torch.bool)
    while todo.any():
        idx = todo.nonzero(as_tuple=True)
        dd, cc = d[idx], c[idx]
        x = torch.randn(dd.shape, generator=generator, dtype=shape.dtype, device=shape.device)
        u = torch.rand(dd.shape, generator=generator, dtype=shape.dtype, device=shape.device)
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
    u = torch.rand(shape.shape, generator=generator, dtype=DTYPE, device=shape.device)
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
    classes = torch.as_tensor(classes, dtype=torch.long, device=theta.device)
    num_classes = theta.shape[-1]
    one_hot = torch.nn.functional.one_hot(classes, num_classes).to(DTYPE)
    lifted = (theta * one_hot).sum(-1)
    e = torch.rand(one_hot.shape, generator=generator, dtype=DTYPE, device=theta.device).clamp_min(1e-300)
    x = -e.log()
    g = sample_gamma(lifted + 1.0, generator)
    x = torch.where(one_hot.bool(), g.unsqueeze(-1), x)
    x = x.clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)


def sample_dirichlet(alpha: Tensor, generator: torch.Generator) -> Tensor:
    """One draw of ``Dir(alpha)`` per row of ``alpha (..., M)`` (normalised gammas, any ``alpha > 0``)."""
    x = gamma_variates(torch.as_tensor(alpha, dtype=DTYPE), 1.0, generator).clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)


def sample_gaussian(loc: Tensor, cov: Tensor, generator: torch.Generator) -> Tensor:
    """``N(loc, cov)`` draws for batches ``loc (..., d)``, ``cov (..., d, d)``."""
    loc, cov = torch.as_tensor(loc, dtype=DTYPE), torch.as_tensor(cov, dtype=DTYPE)
    z = torch.randn(
        torch.broadcast_shapes(loc.shape, cov.shape[:-1]), generator=generator, dtype=DTYPE, device=loc.device
    )
    return _scaled(loc, cov, z)


def _scaled(loc: Tensor, cov: Tensor, z: Tensor) -> Tensor:
    """``loc + L z`` with ``L L^T = cov``: standard normals ``z (..., d)`` mapped to ``N(loc, cov)`` (broadcasting)."""
    return loc + (torch.linalg.cholesky(cov) @ z.unsqueeze(-1)).squeeze(-1)


def sample_sequences(
    loc: Tensor,
    between: Tensor,
    within: Tensor,
    classes: Tensor,
    num_frames: int,
    generator: torch.Generator,
    correlation: float = 0.0,
) -> Tensor:
    """Output sequences from the sequence-aware model: ``(K, num_frames, M)`` for ``classes (K,)``.

    Each sequence draws its look ``mu_k ~ N(loc[c_k], between[c_k])``, then its frames'
    log-ratio coordinates ``y ~ N(mu_k, within)``, mapped to the simplex by ``softmax(H^T y)``.
    ``loc (M, d)``, ``between (M, d, d)``, ``within (d, d)`` (or ``(K, 1, d, d)``: one per sequence).
    With ``correlation`` (in (-1, 1)) the frames' scatter about the look is an AR(1) series with that lag-1
    correlation (:mod:`hbni_pyro.frame_correlation`); 0 draws them i.i.d.
    """
    classes = torch.as_tensor(classes, dtype=torch.long, device=loc.device)
    look = sample_gaussian(loc[classes], between[classes], generator)
    z = ar1_normals(look.shape[:-1] + (num_frames, look.shape[-1]), correlation, generator, look.device)
    y = _scaled(look.unsqueeze(-2), within, z)
    return torch.softmax(y @ helmert_basis(loc.shape[-1] + 1, DTYPE, loc.device), -1).clamp_min(torch.finfo(DTYPE).tiny)
