"""How much a stream's outputs so far support each class, averaged over the paper's model's posterior draws.

The likelihood terms are those of :mod:`hbni_pyro.distributions.density`.

The evidence classes share one surface, which :class:`hbni_pyro.HBNIFilter` reads:
``features(obs)`` is the per-frame statistic whose running sum the filter keeps, and
``log_evidence(stats, counts)`` is ``log mean_s p(o_1:n | c, draw s)`` ``(K, M)`` for ``K``
blocks of outputs given their summed features and frame counts. The draws are averaged in log space,
summing in index order (:func:`hbni_pyro.distributions.draws.logsumexp_in_order`) so that one stream and a
batch of streams agree exactly. Everything is computed on the device of the draws (the statistics must be
there too).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.density import lifted_normaliser
from hbni_pyro.distributions.draws import CHUNK_ELEMENTS, chunks, logsumexp_in_order


class PaperEvidence:
    """The paper's model: per-frame feature ``log o``; draws ``theta (S, M)``."""

    def __init__(self, draws: dict[str, Tensor]) -> None:
        theta = draws["theta"]
        self.num_classes = theta.shape[1]
        self.feature_size = self.num_classes
        # (M, 1, S), contiguous over draws so every (M, k, S) term tensor reduces over its inner dim
        self._offset = lifted_normaliser(theta, self.num_classes).T.contiguous().unsqueeze(1)
        self._theta = theta.T.contiguous().unsqueeze(1)

    def features(self, obs: Tensor) -> Tensor:
        return obs.log()

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        M, S = self.num_classes, self._theta.shape[-1]
        stats = stats.T.contiguous().unsqueeze(-1)  # (M, K, 1)
        counts = counts.reshape(1, -1, 1)
        out = torch.empty(M, stats.shape[1], dtype=stats.dtype, device=stats.device)
        for start in chunks(stats.shape[1], S * M):
            end = start + max(1, CHUNK_ELEMENTS // (S * M))
            terms = torch.addcmul(counts[:, start:end] * self._offset, self._theta, stats[:, start:end])  # (M, k, S)
            out[:, start:end] = logsumexp_in_order(terms)
        return (out - math.log(S)).T
