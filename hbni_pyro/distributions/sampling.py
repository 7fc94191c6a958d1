"""Seeded draws of the distributions every noise model samples from: gammas, Dirichlets, Gaussians.

Gamma draws with shape >= 1 use Marsaglia and Tsang's squeeze method, vectorised over all entries, so every draw
is reproducible from the generator alone; shapes below 1 use the boost ``Ga(a) = Ga(a + 1) * U ** (1 / a)``.
A Dirichlet draw is normalised independent gammas. Draws are made on the device of the parameters, with a generator
of that device (:func:`hbni_infra.streams.torch_generator`). On ``meta`` parameters (shapes only) there is no
generator (``None``) and the draws are shapes without values.

Every sampler checks its parameters (finite, in the range it can sample) and its generator (a ``torch.Generator``
on the parameters' device: never torch's global stream) before drawing, and raises a ``TypeError`` or
``ValueError`` naming the argument; the rejection loop of the gamma draws stops after :data:`MAX_ROUNDS` rounds
with a ``RuntimeError`` instead of looping on. The noise models' output samplers
(:func:`hbni_pyro.sample_outputs`, :func:`hbni_pyro.sample_sequences`) are built on these.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from hbni_pyro.validation import DTYPE, has_values
from hbni_infra.checks import as_generator

MAX_ROUNDS = 400
"""Most rounds of the gamma draws' rejection loop. With every shape >= 1 a round accepts each entry with
probability >= 0.95, so 400 rounds leave an entry undrawn with probability below 1e-500: reaching the bound
means the shapes were not what the checks let through, and it raises."""


def check_values(name: str, x: Tensor, low: float, closed: bool, what: str) -> Tensor:
    """``x`` unchanged when every entry is finite and above ``low`` (``>= low`` if ``closed``), else a ``ValueError``
    naming ``name``, the first bad entry and ``what`` needs the range; ``meta`` tensors pass."""
    if has_values(x) and x.numel():
        bad = ~torch.isfinite(x) | ((x < low) if closed else (x <= low))
        if bool(bad.any()):
            index = tuple(int(i) for i in bad.nonzero()[0])
            raise ValueError(
                f"{name}: expected finite entries {'>=' if closed else '>'} {low:g} ({what}), "
                f"got {float(x[index])} at index {index}"
            )
    return x


def as_params(name: str, value: Any) -> Tensor:
    """``value`` as a float64 tensor, else a ``TypeError`` naming ``name``."""
    if isinstance(value, Tensor):
        if value.dtype == torch.bool or value.is_complex():
            raise TypeError(f"{name}: expected a real tensor, got dtype {value.dtype}")
        return value.to(DTYPE)
    try:
        return torch.as_tensor(value, dtype=DTYPE)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise TypeError(f"{name}: expected real numbers, got {type(value).__name__}") from exc


def as_classes(classes: Any, num_classes: int, device: torch.device, name: str = "classes") -> Tensor:
    """Integer classes in ``[0, num_classes)`` as int64 on ``device`` (whole floats accepted), else an error
    naming ``name``."""
    try:
        x = torch.as_tensor(classes, device=device)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise TypeError(f"{name}: expected integer classes, got {type(classes).__name__}") from exc
    if x.dtype == torch.bool or x.is_complex():
        raise TypeError(f"{name}: expected integer classes, got dtype {x.dtype}")
    if x.is_floating_point() and has_values(x) and not bool((x == x.round()).all()):
        raise TypeError(f"{name}: expected integer classes, got non-integer values")
    x = x.long()
    if has_values(x) and x.numel() and bool(((x < 0) | (x >= num_classes)).any()):
        bad = x[(x < 0) | (x >= num_classes)][0]
        raise ValueError(f"{name}: expected classes in [0, {num_classes}), got {int(bad)}")
    return x


def sample_gamma(shape: Tensor, generator: torch.Generator | None) -> Tensor:
    """Draw ``Ga(shape, 1)`` for every entry of ``shape`` (all entries finite and >= 1); shapes only on ``meta``."""
    shape = check_values("shape", as_params("shape", shape), 1.0, True, "Marsaglia and Tsang's method")
    generator = as_generator("generator", generator, shape.device)
    if not has_values(shape):
        return torch.empty_like(shape)
    d = shape - 1.0 / 3.0
    c = 1.0 / torch.sqrt(9.0 * d)
    out = torch.empty_like(shape)
    todo = torch.ones_like(shape, dtype=torch.bool)
    for _ in range(MAX_ROUNDS):
        if not todo.any():
            return out
        idx = todo.nonzero(as_tuple=True)
        dd, cc = d[idx], c[idx]
        x = torch.randn(dd.shape, generator=generator, dtype=shape.dtype, device=shape.device)
        u = torch.rand(dd.shape, generator=generator, dtype=shape.dtype, device=shape.device)
        v = (1 + cc * x) ** 3
        ok = (v > 0) & (u.log() < 0.5 * x * x + dd - dd * v + dd * v.clamp_min(1e-300).log())
        out[tuple(i[ok] for i in idx)] = (dd * v)[ok]
        todo[tuple(i[ok] for i in idx)] = False
    if not todo.any():
        return out
    raise RuntimeError(f"sample_gamma: {int(todo.sum())} draws still rejected after {MAX_ROUNDS} rounds")


def gamma_variates(shape: Tensor, scale: Tensor | float, generator: torch.Generator) -> Tensor:
    """Draw ``Ga(shape, scale)`` (shape-scale) for every entry; any finite ``shape > 0`` and ``scale > 0``.

    Shapes below 1 use the boost ``Ga(a) = Ga(a + 1) * U ** (1 / a)``.
    """
    shape = check_values("shape", as_params("shape", shape), 0.0, False, "a gamma shape")
    check_values("scale", as_params("scale", scale), 0.0, False, "a gamma scale")
    generator = as_generator("generator", generator, shape.device)
    small = shape < 1
    x = sample_gamma(torch.where(small, shape + 1, shape), generator)
    u = torch.rand(shape.shape, generator=generator, dtype=DTYPE, device=shape.device)
    return torch.where(small, x * u ** (1 / shape), x) * scale


def sample_dirichlet(alpha: Tensor, generator: torch.Generator) -> Tensor:
    """One draw of ``Dir(alpha)`` per row of ``alpha (..., M)`` (normalised gammas, any finite ``alpha > 0``)."""
    alpha = check_values("alpha", as_params("alpha", alpha), 0.0, False, "Dirichlet concentrations")
    x = gamma_variates(alpha, 1.0, generator).clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)


def sample_gaussian(loc: Tensor, cov: Tensor, generator: torch.Generator) -> Tensor:
    """``N(loc, cov)`` draws for batches ``loc (..., d)``, ``cov (..., d, d)`` (finite; ``cov`` positive definite)."""
    loc = check_values("loc", as_params("loc", loc), -math.inf, False, "a mean")
    cov = check_values("cov", as_params("cov", cov), -math.inf, False, "a covariance")
    generator = as_generator("generator", generator, loc.device)
    _check_square(loc, cov)
    z = torch.randn(
        torch.broadcast_shapes(loc.shape, cov.shape[:-1]), generator=generator, dtype=DTYPE, device=loc.device
    )
    return to_gaussian(loc, cov, z)


def _check_square(loc: Tensor, cov: Tensor) -> None:
    if loc.dim() < 1 or cov.dim() < 2 or cov.shape[-1] != cov.shape[-2] or cov.shape[-1] != loc.shape[-1]:
        raise ValueError(
            f"cov: expected shape (..., d, d) for loc (..., d), got {tuple(cov.shape)} and {tuple(loc.shape)}"
        )


def to_gaussian(loc: Tensor, cov: Tensor, z: Tensor) -> Tensor:
    """``loc + L z`` with ``L L^T = cov``: standard normals ``z (..., d)`` mapped to ``N(loc, cov)`` (broadcasting)."""
    _check_square(loc, cov)
    factor, info = torch.linalg.cholesky_ex(cov)
    if has_values(info) and bool((info != 0).any()):
        raise ValueError("cov: expected positive definite covariance matrices, got one that is not")
    return loc + (factor @ z.unsqueeze(-1)).squeeze(-1)
