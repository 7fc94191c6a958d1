"""Is a filter's confidence honest? Reliability, expected calibration error and macro-observation checks.

A filter is calibrated when, among the moments it says "class m with probability q", it is
right a share q of the time. Two views, both on labelled held-out streams:

- :func:`reliability`: every prefix of every stream, its top posterior probability against
  whether the top class is right, binned (the reliability diagram) and summarised by the
  expected calibration error (ECE: the bins' mean gap, weighted by their share of prefixes).
- :func:`threshold_checks`: the macro-observation process at each threshold. It emits a label
  only once its confidence reaches the threshold; a stream that runs out of frames first is a
  timeout, whose label is not emitted. Honest means the emitted labels are right at least
  ``threshold`` of the time; timid means it times out often or needs many frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor

from hbni_pyro.filters import StreamingFilter, decide
from hbni_pyro.macro import MacroObservationProcess
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float, as_int, as_probability


class Reliability(NamedTuple):
    """A binned reliability diagram: per bin ``edges[b]..edges[b+1]`` of confidence, the mean
    ``confidence``, the ``accuracy`` and ``count`` of the predictions in it (NaN where empty); ``ece``."""

    edges: Tensor
    confidence: Tensor
    accuracy: Tensor
    count: Tensor
    ece: float


def reliability(confidence: Tensor, correct: Tensor, num_bins: int = 10, low: float = 0.0) -> Reliability:
    """Bin predictions by confidence (equal-width bins on ``[low, 1]``) and compare with their accuracy.

    Args:
        confidence: any shape, probabilities of the predicted class.
        correct: same shape, bool: whether the prediction was right.
        num_bins: number of bins.
        low: left edge of the first bin (``1 / M`` is the least a top class can have).

    The diagram's tensors are on ``confidence``'s device.
    """
    num_bins = as_int("num_bins", num_bins, minimum=1)
    low = as_float("low", low, 0.0, 1.0, high_open=True)
    confidence = confidence.reshape(-1).to(DTYPE)
    correct = correct.reshape(-1).to(confidence.device, DTYPE)
    if confidence.shape != correct.shape or confidence.numel() == 0:
        raise ValueError(
            f"confidence, correct: expected equal non-empty shapes, got {tuple(confidence.shape)} and {tuple(correct.shape)}"
        )
    like = dict(dtype=DTYPE, device=confidence.device)
    edges = torch.linspace(low, 1.0, num_bins + 1, **like)
    index = torch.bucketize(confidence, edges[1:-1], right=True)
    count = torch.zeros(num_bins, **like).index_add_(0, index, torch.ones_like(confidence))
    conf = torch.zeros(num_bins, **like).index_add_(0, index, confidence) / count
    acc = torch.zeros(num_bins, **like).index_add_(0, index, correct) / count
    used = count > 0
    ece = float(((conf - acc).abs()[used] * count[used]).sum() / count.sum())
    return Reliability(edges, conf, acc, count, ece)


def stream_reliability(filter: StreamingFilter, streams: Tensor, truth: Tensor, num_bins: int = 10) -> Reliability:
    """:func:`reliability` of ``filter``'s posterior after every prefix of every stream ``(B, N, M)``, on the
    filter's device."""
    probs = filter.run(streams)
    correct = decide(probs) == torch.as_tensor(truth).to(probs.device).view(-1, 1)
    return reliability(probs.max(-1).values, correct, num_bins, low=1.0 / filter.num_classes)


def binomial_stderr(p: float, n: int) -> float:
    """Standard error ``sqrt(p (1 - p) / n)`` of a proportion from ``n`` trials (NaN when ``n = 0``)."""
    return math.sqrt(p * (1 - p) / n) if n else float("nan")


def threshold_checks(
    filter: StreamingFilter,
    streams: Tensor,
    truth: Tensor,
    thresholds: Sequence[float] = (0.9, 0.95, 0.99),
    max_frames: int | None = None,
) -> dict[str, dict[str, Any]]:
    """Run the macro-observation process at each threshold on labelled streams ``(B, N, M)``.

    Returns, per threshold (key ``f"{t:g}"``): ``emitted_accuracy`` (share of emitted labels
    that are right) and its binomial ``emitted_stderr``, ``emitted`` (count), ``timeout_rate``
    and its binomial ``timeout_stderr``, ``mean_frames`` (frames used, a timeout counting the
    whole budget) and its standard error ``frames_stderr`` (sample sd over ``sqrt(B)``), and
    ``overall_accuracy`` (the label at the stop, timeouts included, against the truth).
    """
    thresholds = [as_probability(f"thresholds[{i}]", t, allow_zero=False) for i, t in enumerate(thresholds)]
    max_frames = streams.shape[1] if max_frames is None else as_int("max_frames", max_frames, minimum=1)
    truth = torch.as_tensor(truth).long().to(filter.device)
    out: dict[str, dict[str, Any]] = {}
    for t in thresholds:
        process = MacroObservationProcess(filter, threshold=t, max_frames=max_frames)
        batch = process.run_batch(streams)
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
    return out
