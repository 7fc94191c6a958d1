"""When to stop: the macro-observation process at each threshold on labelled streams, and the stopping confidence
that keeps a promised accuracy.

- :func:`threshold_checks`: the macro-observation process at each threshold. It emits a label
  only once its confidence reaches the threshold; a stream that runs out of frames first is a
  timeout, whose label is not emitted. Honest means the emitted labels are right at least
  ``threshold`` of the time; timid means it times out often or needs many frames.
- :func:`fit_stop_threshold`: the lowest confidence at which to stop so that the emitted labels are still
  right at least a target share of the time on labelled calibration sequences (a conservative filter stops
  earlier, an overconfident one later); with :func:`cross_fit`, on sequences the filter was not fitted on.
  :func:`fit_stop_unlabelled` chooses it on unlabelled streams, scored by the filter's own posterior given each
  whole stream.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor

from hbni_pyro.filters.macro import MacroObservationProcess
from hbni_pyro.filters.streaming import StreamingFilter
from hbni_pyro.validation import DTYPE, as_labels
from hbni_infra.checks import as_float, as_int, as_probability
from hbni_infra.stats import wilson_interval


def binomial_stderr(p: float, n: int) -> float:
    """Standard error ``sqrt(p (1 - p) / n)`` of a proportion from ``n`` trials (NaN when ``n = 0``)."""
    return math.sqrt(p * (1 - p) / n) if n else float("nan")


def threshold_checks(
    filter: StreamingFilter,
    streams: Tensor,
    truth: Tensor,
    thresholds: Sequence[float] = (0.9, 0.95, 0.99),
    max_frames: int | None = None,
    stops: Mapping[float, float] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run the macro-observation process at each threshold on labelled streams ``(B, N, M)``.

    ``stops`` maps a threshold ``t`` (the accuracy the process promises) to the confidence at which it stops
    (:func:`fit_stop_threshold`); a threshold it does not name is its own stop. Each entry then also says
    ``stop``.

    Returns, per threshold (key ``f"{t:g}"``): ``emitted_accuracy`` (share of emitted labels
    that are right) and its binomial ``emitted_stderr``, ``emitted`` (count), ``timeout_rate``
    and its binomial ``timeout_stderr``, ``mean_frames`` (frames used, a timeout counting the
    whole budget) and its standard error ``frames_stderr`` (sample sd over ``sqrt(B)``), and
    ``overall_accuracy`` (the label at the stop, timeouts included, against the truth).
    """
    thresholds = [as_probability(f"thresholds[{i}]", t, allow_zero=False) for i, t in enumerate(thresholds)]
    streams, truth = labelled_streams(filter, streams, truth)
    max_frames = streams.shape[1] if max_frames is None else as_int("max_frames", max_frames, minimum=1)
    out: dict[str, dict[str, Any]] = {}
    stop_at = [float((stops or {}).get(t, t)) for t in thresholds]
    process = MacroObservationProcess(filter, max_frames=max_frames)
    for t, stop, batch in zip(thresholds, stop_at, process.run_thresholds(streams, stop_at)):
        emitted = ~batch.timed_out
        right = batch.label == truth
        n = int(emitted.sum())
        acc = float(right[emitted].to(DTYPE).mean()) if n else float("nan")
        timeouts, frames = float(batch.timed_out.to(DTYPE).mean()), batch.frames_used.to(DTYPE)
        out[f"{t:g}"] = {
            "emitted_accuracy": acc,
            "emitted_stderr": binomial_stderr(acc, n),
            "emitted": n,
            "timeout_rate": timeouts,
            "timeout_stderr": binomial_stderr(timeouts, len(frames)),
            "mean_frames": float(frames.mean()),
            "frames_stderr": float(frames.std() / math.sqrt(len(frames))) if len(frames) > 1 else float("nan"),
            "overall_accuracy": float(right.to(DTYPE).mean()),
        }
        if stops is not None:
            out[f"{t:g}"]["stop"] = stop
    return out


def _listed(names: Sequence[str] | None) -> str:
    return str(list(names)) if names else "(unnamed)"


def labelled_streams(filter: StreamingFilter, streams: Any, truth: Any, where: str = "") -> tuple[Tensor, Tensor]:
    """``streams (B, N, M)`` of ``filter``'s ``M`` classes and their classes ``truth (B,)`` in ``[0, M)``, checked;
    ``truth`` as int64 on the filter's device. ``where`` prefixes the argument names in errors (``"folds[1]."``)."""
    if not isinstance(streams, Tensor) or streams.dim() != 3:
        got = tuple(streams.shape) if isinstance(streams, Tensor) else type(streams).__name__
        raise ValueError(f"{where}streams: expected a tensor (B, N, M) of labelled streams, got {got}")
    if streams.shape[2] != filter.num_classes:
        raise ValueError(
            f"{where}streams: expected outputs of the filter's {filter.num_classes} classes, got {streams.shape[2]}"
        )
    truth = as_labels(truth, streams.shape[0], filter.num_classes, name=f"{where}truth")
    if (truth < 0).any():
        raise ValueError(f"{where}truth: expected the class of every stream, got -1 (unknown)")
    return streams, truth.to(filter.device)


DEFAULT_STOPS = (0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98, 0.99, 0.995, 0.999)
"""Candidate stopping confidences of :func:`fit_stop_threshold`."""


class StopFit(NamedTuple):
    """Result of :func:`fit_stop_threshold`: the chosen ``stop``, the ``target`` accuracy, and per candidate of
    ``grid`` the emitted accuracy on the labelled streams, its Wilson ``lower`` bound, the mean frames and the
    timeout rate."""

    stop: float
    target: float
    grid: list[float]
    emitted_accuracy: list[float]
    lower: list[float]
    mean_frames: list[float]
    timeout_rate: list[float]


class Fold(NamedTuple):
    """A filter and labelled streams it was not fitted on: ``streams (B, N, M)``, ``truth (B,)``."""

    filter: StreamingFilter
    streams: Tensor
    truth: Tensor


def cross_fit(fit: Callable[[Tensor, int], StreamingFilter], outputs: Tensor, folds: int = 2) -> list[Fold]:
    """Split each class's labelled sequences ``outputs (C, S, N, M)`` (``S`` sequences of ``N`` frames of true
    class ``c``) into ``folds`` interleaved folds (sequence ``s`` in fold ``s % folds``), and for each fold ``k``
    build ``fit(outputs without fold k, k)``: a filter fitted on the other folds, paired with fold ``k``'s
    streams as its held-out data."""
    folds = as_int("folds", folds, minimum=2)
    if outputs.dim() != 4 or outputs.shape[1] < folds:
        raise ValueError(f"outputs: expected (C, S, N, M) with S >= folds={folds}, got {tuple(outputs.shape)}")
    index = torch.arange(outputs.shape[1])
    out = []
    for k in range(folds):
        held = outputs[:, index % folds == k]
        truth = torch.arange(held.shape[0]).repeat_interleave(held.shape[1])
        out.append(Fold(fit(outputs[:, index % folds != k], k), held.reshape(-1, *held.shape[2:]), truth))
    return out


def fit_stop_threshold(
    filter: StreamingFilter | Sequence[Fold],
    streams: Tensor | None,
    truth: Tensor | None,
    target: float,
    max_frames: int | None = None,
    grid: Sequence[float] | None = None,
    z: float = 1.0,
) -> StopFit:
    """The lowest stopping confidence at which a macro-observation process is right at least ``target`` of the
    time on labelled streams ``(B, N, M)`` (calibration sequences).

    A filter whose confidence is honest but conservative (the sequence model's marginal posterior on correlated
    frames) is right more often than it says; stopping once its confidence reaches ``stop < target`` then keeps
    the promise ``target`` in fewer frames. ``stop`` is the lowest candidate of ``grid`` (``None``:
    :data:`DEFAULT_STOPS` above ``1 / M``) whose emitted labels' Wilson lower bound at ``z`` standard errors is at
    least ``target`` (``z = 0``: the emitted accuracy itself); when none is (too few sequences to show it),
    ``target`` itself.

    ``filter`` may instead be the :class:`Fold` s of :func:`cross_fit` (``streams`` and ``truth`` ``None``): the
    process then runs each fold's filter on that fold's streams and pools the counts, so that the stop is chosen
    on sequences the filter was not fitted on (a filter judged on its own fitting data looks more accurate than it
    is on new data).
    """
    target = as_probability("target", target, allow_zero=False)
    z = as_float("z", z, 0.0, math.inf, high_open=True)
    if isinstance(filter, StreamingFilter):
        folds = [Fold(filter, streams, truth)]
    else:
        folds = list(filter)
        if not folds or not all(isinstance(f, Fold) for f in folds) or streams is not None or truth is not None:
            raise TypeError("filter: expected a StreamingFilter, or a non-empty list of Fold with streams=truth=None")
    num_classes, names = folds[0].filter.num_classes, folds[0].filter.class_names
    for k, fold in enumerate(folds):
        classes = fold.filter.class_names
        if fold.filter.num_classes != num_classes or (classes and names and tuple(classes) != tuple(names)):
            raise ValueError(
                f"filter: fold {k}'s filter has {fold.filter.num_classes} classes {_listed(classes)}, fold 0's "
                f"{num_classes} {_listed(names)}: the folds pooled into one stop must share their classes"
            )
        where = "" if isinstance(filter, StreamingFilter) else f"filter[{k}]."
        folds[k] = Fold(fold.filter, *labelled_streams(fold.filter, fold.streams, fold.truth, where))
    grid = _stop_grid(grid, num_classes)
    right, emitted, frames, timeouts, total = (torch.zeros(len(grid), dtype=DTYPE) for _ in range(5))
    for fold in folds:
        checks = threshold_checks(fold.filter, fold.streams, fold.truth, grid, max_frames)
        for i, t in enumerate(grid):
            row, b = checks[f"{t:g}"], len(fold.truth)
            right[i] += round(row["emitted_accuracy"] * row["emitted"]) if row["emitted"] else 0
            emitted[i] += row["emitted"]
            frames[i] += row["mean_frames"] * b
            timeouts[i] += row["timeout_rate"] * b
            total[i] += b
    return _lowest_stop(grid, right, emitted, frames / total, timeouts / total, target, z)


def _lowest_stop(
    grid: list[float], right: Tensor, emitted: Tensor, frames: Tensor, timeouts: Tensor, target: float, z: float
) -> StopFit:
    """The :class:`StopFit` of ``right`` of ``emitted`` labels (rounded to counts) per candidate of ``grid``: the
    lowest candidate whose Wilson lower bound at ``z`` standard errors is at least ``target``, else ``target``."""
    confidence = math.erf(z / math.sqrt(2.0))  # two-sided: the interval's lower end lies z standard errors down
    lower = [wilson_interval(round(float(k)), int(n), confidence)[0] if n else 0.0 for k, n in zip(right, emitted)]
    stop = next((t for t, bound in zip(grid, lower) if bound >= target), target)
    return StopFit(stop, target, grid, (right / emitted).tolist(), lower, frames.tolist(), timeouts.tolist())


def fit_stop_unlabelled(
    filter: StreamingFilter,
    streams: Tensor,
    target: float,
    max_frames: int | None = None,
    grid: Sequence[float] | None = None,
    z: float = 1.0,
    labels: Tensor | None = None,
) -> StopFit:
    """:func:`fit_stop_threshold` without labels: the lowest stopping confidence at which the process's emitted
    labels are right at least ``target`` of the time, each stream's true class standing in by ``filter``'s own
    posterior after the whole stream ``(B, N, M)``.

    A label emitted after ``n`` frames is right with probability ``q(label)``, where ``q`` is the class posterior
    given everything the stream shows; the filter's posterior after all ``N`` frames is that ``q`` as far as its
    model is right, so the mean of ``q(label)`` over the emitted labels estimates their accuracy without a label
    (an unbiased estimate under a calibrated model, a low one under a conservative model, as the sequence model is
    on camera frames). ``emitted_accuracy`` in the result is that estimate; the expected number of right labels,
    rounded, enters the Wilson bound at ``z`` standard errors. Streams should be ones the filter may meet, such as
    the unlabelled streams a model was adapted on (:func:`hbni_pyro.adapt`), and long enough to tell the classes
    apart at their end: a stream whose final posterior is unsure weighs its emitted label by that unsureness.
    ``labels (B,)``, ``-1`` where unknown (``None``: all unknown): a known class stands for itself.
    """
    target = as_probability("target", target, allow_zero=False)
    z = as_float("z", z, 0.0, math.inf, high_open=True)
    if not isinstance(filter, StreamingFilter):
        raise TypeError(f"filter: expected a StreamingFilter, got {type(filter).__name__}")
    streams = torch.as_tensor(streams)
    if streams.dim() != 3 or streams.shape[0] < 1 or streams.shape[-1] != filter.num_classes:
        raise ValueError(
            f"streams: expected (B, N, {filter.num_classes}) outputs with B >= 1, got {tuple(streams.shape)}"
        )
    max_frames = streams.shape[1] if max_frames is None else as_int("max_frames", max_frames, minimum=1)
    grid = _stop_grid(grid, filter.num_classes)
    full = filter.run(streams)[:, -1]  # (B, M): the posterior given the whole stream
    if labels is not None:
        labels = torch.as_tensor(labels)
        if labels.shape != streams.shape[:1] or labels.is_floating_point() or (labels >= filter.num_classes).any():
            raise ValueError(
                f"labels: expected {streams.shape[0]} integer classes below {filter.num_classes} (-1: unknown), "
                f"got shape {tuple(labels.shape)}"
            )
        known = (labels >= 0).to(full.device)
        one_hot = torch.nn.functional.one_hot(labels.clamp_min(0).to(full.device), filter.num_classes).to(full.dtype)
        full = torch.where(known.unsqueeze(-1), one_hot, full)
    process = MacroObservationProcess(filter, max_frames=max_frames)
    right, emitted, frames, timeouts = (torch.zeros(len(grid), dtype=DTYPE) for _ in range(4))
    for i, batch in enumerate(process.run_thresholds(streams, grid)):
        shown = ~batch.timed_out
        right[i] = full[shown].gather(-1, batch.label[shown].unsqueeze(-1)).sum().cpu()
        emitted[i] = int(shown.sum())
        frames[i] = float(batch.frames_used.to(DTYPE).mean())
        timeouts[i] = float(batch.timed_out.to(DTYPE).mean())
    return _lowest_stop(grid, right, emitted, frames, timeouts, target, z)


def _stop_grid(grid: Sequence[float] | None, num_classes: int) -> list[float]:
    """The candidate stops of ``grid`` (``None``: :data:`DEFAULT_STOPS`) above ``1 / num_classes``."""
    low = 1.0 / num_classes
    grid = [float(t) for t in (DEFAULT_STOPS if grid is None else grid) if float(t) > low]
    if not grid:
        raise ValueError(f"grid: expected candidate stops in ({low:g}, 1], got none")
    return grid
