"""Pure update steps of the confusion-aware model's MH sampler, vectorised over chains.

The class move is the frame-level kernels' shared one (:mod:`hbni_pyro.mcmc.class_moves`, called with
``beta``) and the ``(kappa, gamma)`` move the paper's (:mod:`hbni_pyro.models.paper.steps`). This module adds the
moves of the concentration matrix and of the confusions' hyperparameters. ``log_conc (..., M, M)`` holds ``log theta_c`` on its diagonal and
``log beta_cj`` off it; given the classes, each row depends on the data only through its
class's count and log-output sums (:func:`hbni_pyro.distributions.density.assigned_log_lik`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.density import assigned_log_lik


def split_conc(log_conc: Tensor) -> tuple[Tensor, Tensor]:
    """``log_conc (..., M, M)`` -> ``theta (..., M)`` (diagonal) and ``beta (..., M, M)`` (diagonal set to 1)."""
    eye = torch.eye(log_conc.shape[-1], dtype=torch.bool, device=log_conc.device)
    return log_conc.diagonal(dim1=-2, dim2=-1).exp(), log_conc.masked_fill(eye, 0.0).exp()


def conc_log_target(
    log_conc: Tensor, counts: Tensor, sums: Tensor, kappa: Tensor, gamma: Tensor, beta_loc: Tensor, beta_scale: Tensor
) -> Tensor:
    """Unnormalised log density of every entry's row and prior term, per row ``(..., M)`` plus per entry.

    Returns ``(..., M, M)``: entry ``[c, j]`` is row ``c``'s log likelihood plus the prior of entry
    ``(c, j)`` on the log scale (``Ga(kappa, gamma)`` for the diagonal ``log theta_c`` with its
    Jacobian, ``N(beta_loc, beta_scale^2)`` for ``log beta_cj``). A move of entry ``(c, j)``
    changes only row ``c``'s likelihood and that entry's prior, so its MH ratio is a difference
    of this tensor's ``[c, j]`` entries.
    """
    theta, beta = split_conc(log_conc)
    row = assigned_log_lik(counts, sums, theta, beta)
    diag = kappa[..., None, None] * log_conc - log_conc.exp() / gamma[..., None, None]
    off = -0.5 * ((log_conc - beta_loc[..., None, None]) / beta_scale[..., None, None]) ** 2
    eye = torch.eye(log_conc.shape[-1], dtype=torch.bool, device=log_conc.device)
    return row.unsqueeze(-1) + torch.where(eye, diag, off)


def update_concentrations(
    log_conc: Tensor,
    counts: Tensor,
    sums: Tensor,
    kappa: Tensor,
    gamma: Tensor,
    beta_loc: Tensor,
    beta_scale: Tensor,
    step: Tensor,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor]:
    """A Gaussian random walk on each entry of ``log_conc``, one column at a time.

    Entries of one column sit in different rows, which are independent given the classes and
    hyperparameters, so a column moves in one vectorised step; the ``M`` columns go in turn.

    Args:
        counts ``(..., M)``, sums ``(..., M, M)``: per-class statistics of the outputs (labelled and assigned).
        step: ``(..., M, M)`` proposal standard deviations on the log scale.

    Returns:
        new ``log_conc (..., M, M)`` and ``accepted (..., M, M)`` bool.
    """
    num_classes = log_conc.shape[-1]
    like = dict(dtype=log_conc.dtype, device=log_conc.device)
    accepted = torch.zeros(log_conc.shape, dtype=torch.bool, device=log_conc.device)
    eps = torch.randn(log_conc.shape, generator=generator, **like)
    log_u = torch.rand(log_conc.shape, generator=generator, **like).log()
    args = (counts, sums, kappa, gamma, beta_loc, beta_scale)
    current = conc_log_target(log_conc, *args)
    for j in range(num_classes):
        proposal = log_conc.clone()
        proposal[..., j] += step[..., j] * eps[..., j]
        target = conc_log_target(proposal, *args)
        ok = log_u[..., j] < target[..., j] - current[..., j]
        log_conc = torch.where(ok.unsqueeze(-1), proposal, log_conc)
        current = torch.where(ok.unsqueeze(-1), target, current)
        accepted[..., j] = ok
    return log_conc, accepted


def off_diagonal_logs(log_conc: Tensor) -> Tensor:
    """``(..., M * (M - 1))`` the off-diagonal ``log beta_cj``, row by row (a reshape, not a mask: nothing is read
    back to the host)."""
    M = log_conc.shape[-1]
    return log_conc.flatten(-2)[..., 1:].unflatten(-1, (M - 1, M + 1))[..., :-1].flatten(-2)


def draw_beta_loc(log_beta: Tensor, beta_scale: Tensor, loc_sd: float, generator: torch.Generator) -> Tensor:
    """Exact conditional draw of ``beta_loc`` given the ``log beta (..., K)`` and ``beta_scale (...)``:
    the normal prior ``N(0, loc_sd^2)`` is conjugate."""
    prec = 1 / loc_sd**2 + log_beta.shape[-1] / beta_scale**2
    mean = log_beta.sum(-1) / beta_scale**2 / prec
    return mean + prec.rsqrt() * torch.randn(mean.shape, generator=generator, dtype=mean.dtype, device=mean.device)


def scale_log_target(log_scale: Tensor, log_beta: Tensor, beta_loc: Tensor, scale_sd: float) -> Tensor:
    """Unnormalised ``log p(log beta_scale | log beta, beta_loc)``: half-normal prior, Jacobian included."""
    scale = log_scale.exp()
    resid = ((log_beta - beta_loc.unsqueeze(-1)) ** 2).sum(-1)
    return -0.5 * resid / scale**2 - log_beta.shape[-1] * log_scale - 0.5 * (scale / scale_sd) ** 2 + log_scale


def update_beta_scale(
    log_scale: Tensor, log_beta: Tensor, beta_loc: Tensor, scale_sd: float, step: Tensor, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Gaussian random walk on ``log beta_scale (...)``; returns the new value and ``accepted``."""
    like = dict(dtype=log_scale.dtype, device=log_scale.device)
    proposal = log_scale + step * torch.randn(log_scale.shape, generator=generator, **like)
    ratio = scale_log_target(proposal, log_beta, beta_loc, scale_sd) - scale_log_target(
        log_scale, log_beta, beta_loc, scale_sd
    )
    ok = torch.rand(log_scale.shape, generator=generator, **like).log() < ratio
    return torch.where(ok, proposal, log_scale), ok
