"""Is a filter's confidence honest? The reliability diagram and the expected calibration error.

A filter is calibrated when, among the moments it says "class m with probability q", it is right a share q of the
time. :func:`reliability` takes every prefix of every labelled held-out stream, its top posterior probability
against whether the top class is right, bins them (the reliability diagram) and summarises the bins by the
expected calibration error (ECE: the bins' mean gap, weighted by their share of prefixes). The macro-observation
process's own view, its emitted labels at each threshold, is :func:`hbni_pyro.threshold_checks`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from hbni_pyro.filters.streaming import StreamingFilter, decide
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float, as_int


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
