"""Sampling classifier outputs from the HBNI generative model with an explicit torch.Generator.

``o | c = m ~ Dir(theta_m e_m + 1)`` is drawn as normalised independent gammas:
``x_m ~ Ga(theta_m + 1, 1)`` and ``x_j ~ Ga(1, 1) = Exp(1)`` for ``j != m``. Gamma draws
with shape >= 1 use Marsaglia and Tsang's squeeze method, vectorised over all entries,
so every draw is reproducible from the generator alone. Draws are made on the device of the
parameters, with a generator of that device (:func:`hbni_infra.streams.torch_generator`). On ``meta`` parameters
(shapes only) there is no generator (``None``) and the draws are shapes without values.

Every sampler checks its parameters (finite, in the range it can sample) and its generator (a ``torch.Generator``
on the parameters' device: never torch's global stream) before drawing, and raises a ``TypeError`` or
``ValueError`` naming the argument; the rejection loop of the gamma draws stops after :data:`MAX_ROUNDS` rounds
with a ``RuntimeError`` instead of looping on.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from hbni_pyro.density import helmert_basis
from hbni_pyro.frame_correlation import ar1_normals
from hbni_pyro.validation import DTYPE, has_values
from hbni_infra.checks import as_float, as_generator, as_int

MAX_ROUNDS = 400
"""Most rounds of the gamma draws' rejection loop. With every shape >= 1 a round accepts each entry with
probability >= 0.95, so 400 rounds leave an entry undrawn with probability below 1e-500: reaching the bound
means the shapes were not what the checks let through, and it raises."""


def _check_values(name: str, x: Tensor, low: float, closed: bool, what: str) -> Tensor:
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


def _as_params(name: str, value: Any) -> Tensor:
    """``value`` as a float64 tensor, else a ``TypeError`` naming ``name``."""
    if isinstance(value, Tensor):
        if value.dtype == torch.bool or value.is_complex():
            raise TypeError(f"{name}: expected a real tensor, got dtype {value.dtype}")
        return value.to(DTYPE)
    try:
        return torch.as_tensor(value, dtype=DTYPE)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise TypeError(f"{name}: expected real numbers, got {type(value).__name__}") from exc


def _as_classes(classes: Any, num_classes: int, device: torch.device, name: str = "classes") -> Tensor:
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
    shape = _check_values("shape", _as_params("shape", shape), 1.0, True, "Marsaglia and Tsang's method")
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
    shape = _check_values("shape", _as_params("shape", shape), 0.0, False, "a gamma shape")
    _check_values("scale", _as_params("scale", scale), 0.0, False, "a gamma scale")
    generator = as_generator("generator", generator, shape.device)
    small = shape < 1
    x = sample_gamma(torch.where(small, shape + 1, shape), generator)
    u = torch.rand(shape.shape, generator=generator, dtype=DTYPE, device=shape.device)
    return torch.where(small, x * u ** (1 / shape), x) * scale


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
    theta = _as_params("theta", theta)
    if theta.dim() == 0 or theta.shape[-1] < 2:
        raise ValueError(f"theta: expected shape (..., M) with M >= 2 classes, got {tuple(theta.shape)}")
    _check_values("theta", theta, -1.0, False, "the Dirichlet concentration theta + 1 must be positive")
    num_classes = theta.shape[-1]
    classes = _as_classes(classes, num_classes, theta.device)
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


def sample_dirichlet(alpha: Tensor, generator: torch.Generator) -> Tensor:
    """One draw of ``Dir(alpha)`` per row of ``alpha (..., M)`` (normalised gammas, any finite ``alpha > 0``)."""
    alpha = _check_values("alpha", _as_params("alpha", alpha), 0.0, False, "Dirichlet concentrations")
    x = gamma_variates(alpha, 1.0, generator).clamp_min(torch.finfo(DTYPE).tiny)
    return x / x.sum(-1, keepdim=True)


def sample_gaussian(loc: Tensor, cov: Tensor, generator: torch.Generator) -> Tensor:
    """``N(loc, cov)`` draws for batches ``loc (..., d)``, ``cov (..., d, d)`` (finite; ``cov`` positive definite)."""
    loc = _check_values("loc", _as_params("loc", loc), -math.inf, False, "a mean")
    cov = _check_values("cov", _as_params("cov", cov), -math.inf, False, "a covariance")
    generator = as_generator("generator", generator, loc.device)
    _check_square(loc, cov)
    z = torch.randn(
        torch.broadcast_shapes(loc.shape, cov.shape[:-1]), generator=generator, dtype=DTYPE, device=loc.device
    )
    return _scaled(loc, cov, z)


def _check_square(loc: Tensor, cov: Tensor) -> None:
    if loc.dim() < 1 or cov.dim() < 2 or cov.shape[-1] != cov.shape[-2] or cov.shape[-1] != loc.shape[-1]:
        raise ValueError(
            f"cov: expected shape (..., d, d) for loc (..., d), got {tuple(cov.shape)} and {tuple(loc.shape)}"
        )


def _scaled(loc: Tensor, cov: Tensor, z: Tensor) -> Tensor:
    """``loc + L z`` with ``L L^T = cov``: standard normals ``z (..., d)`` mapped to ``N(loc, cov)`` (broadcasting)."""
    _check_square(loc, cov)
    factor, info = torch.linalg.cholesky_ex(cov)
    if has_values(info) and bool((info != 0).any()):
        raise ValueError("cov: expected positive definite covariance matrices, got one that is not")
    return loc + (factor @ z.unsqueeze(-1)).squeeze(-1)


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
    classes = _as_classes(classes, loc.shape[0], loc.device)
    num_frames = as_int("num_frames", num_frames, minimum=1)
    correlation = as_float("correlation", correlation, -1.0, 1.0, low_open=True, high_open=True)
    look = sample_gaussian(loc[classes], between[classes], generator)
    z = ar1_normals(look.shape[:-1] + (num_frames, look.shape[-1]), correlation, generator, look.device)
    y = _scaled(look.unsqueeze(-2), within, z)
    return torch.softmax(y @ helmert_basis(loc.shape[-1] + 1, DTYPE, loc.device), -1).clamp_min(torch.finfo(DTYPE).tiny)
