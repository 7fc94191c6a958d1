"""Fit a filter's likelihood temper (evidence weight) on labelled output streams: HBNI's or the calibrated peer's.

HBNI models a class's outputs as i.i.d. The frames of one camera sequence share their view,
light and background, so they are correlated and the i.i.d. filter grows overconfident: a
macro-observation process that stops at 95 % then stops too soon and is wrong more often than
5 %. Raising every frame's likelihood to a power ``tau`` (:class:`~hbni_pyro.HBNIFilter`'s
``temper``) counts ``N`` correlated frames as ``tau * N`` independent ones. :func:`fit_temper`
picks ``tau`` on a grid by the mean log posterior of the true class over every prefix of every
stream, a proper scoring rule, so the fitted filter's confidence matches its accuracy on the
calibration streams. The calibrated peer (SSBF on calibrated frames) treats frames as independent too, and gets
its evidence weight the same way.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import torch
from torch import Tensor

from hbni_pyro.filters.streaming import HBNIFilter
from hbni_pyro.validation import DTYPE

__all__ = ["TemperFit", "fit_temper"]

DEFAULT_GRID = torch.arange(1, 21, dtype=DTYPE) / 20
"""Default candidate tempers: 0.05, 0.10, ..., 1.0."""


class TemperFit(NamedTuple):
    """Result of :func:`fit_temper`.

    Attributes:
        temper: the best candidate (the first maximum of ``log_score``).
        grid: ``(G,)`` candidates tried.
        log_score: ``(G,)`` mean log posterior probability of the true class over all stream prefixes.
    """

    temper: float
    grid: Tensor
    log_score: Tensor


def fit_temper(
    posterior: Any,
    streams: Any,
    true_class: Any,
    mode: str = "marginal",
    grid: Any = None,
    *,
    num_draws: int | None = None,
) -> TemperFit:
    """Choose the temper (evidence weight) of a filter that best predicts the true class of labelled streams.

    Args:
        posterior: a fitted :class:`~hbni_pyro.HBNIPosterior` (its :class:`~hbni_pyro.HBNIFilter` is tempered), or
            a filter with a ``tempered(tau)`` method (:class:`~hbni_pyro.HBNIFilter`, or the calibrated peer
            ``make_filter("calibrated", ...)``: SSBF on calibrated frames), whose own temper is ignored.
        streams: ``(B, N, M)`` classifier outputs, one labelled sequence per row.
        true_class: ``(B,)`` integer class of each stream, in ``[0, M)``.
        mode, num_draws: as for :class:`~hbni_pyro.HBNIFilter` (for a posterior only).
        grid: ``(G,)`` candidate tempers in ``(0, 1]``; ``None`` = :data:`DEFAULT_GRID`.

    Returns:
        a :class:`TemperFit`; its ``log_score`` is ``mean_{b, n} log P(c = true_b | o_b,1:n)``, on the
        filter's device.

    Raises:
        ValueError: the posterior's filter counts correlated frames itself (a nonzero ``frame_correlation``).
    """
    grid = DEFAULT_GRID if grid is None else torch.as_tensor(grid, dtype=DTYPE)
    if grid.dim() != 1 or grid.numel() < 1 or not torch.isfinite(grid).all() or ((grid <= 0) | (grid > 1)).any():
        raise ValueError(f"grid: expected a non-empty 1-D sequence of tempers in (0, 1], got {grid.tolist()}")
    rho = getattr(posterior, "frame_correlation", 0.0)
    if rho:
        raise ValueError(
            f"posterior: its filter counts correlated frames itself (frame_correlation {rho:g}); a temper is for the "
            "frame-level models (or a posterior with frame_correlation 0)"
        )
    base = (
        posterior
        if callable(getattr(posterior, "tempered", None))
        else HBNIFilter(posterior, mode, num_draws=num_draws)
    )
    stats, counts = base.statistics(streams)
    truth = torch.as_tensor(true_class)
    if truth.is_floating_point() or truth.dim() != 1 or truth.shape[0] != stats.shape[0]:
        raise ValueError(
            f"true_class: expected {stats.shape[0]} integer labels (one per stream), got dtype {truth.dtype} "
            f"and shape {tuple(truth.shape)}"
        )
    if ((truth < 0) | (truth >= base.num_classes)).any():
        raise ValueError(f"true_class: expected labels in [0, {base.num_classes}), got {truth.unique().tolist()}")
    index = truth.long().to(stats.device).view(-1, 1, 1).expand(-1, stats.shape[1], 1)
    counts = counts.expand(stats.shape[:-1])
    scores = torch.empty(grid.shape[0], dtype=DTYPE, device=stats.device)
    for g, tau in enumerate(grid.tolist()):
        probs = base.tempered(tau).posterior(stats, counts)
        scores[g] = probs.gather(-1, index).clamp_min(torch.finfo(DTYPE).tiny).log().mean()
    return TemperFit(float(grid[int(scores.argmax())]), grid, scores)
