"""How much a stream's outputs so far support each class, averaged over the confusion-aware model's posterior draws.

The likelihood terms are those of :mod:`hbni_pyro.distributions.density`; the surface is that of
:class:`~hbni_pyro.models.paper.evidence.PaperEvidence`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.density import block_log_lik, concentrations, dirichlet_terms
from hbni_pyro.distributions.draws import CHUNK_ELEMENTS, chunks, logsumexp_in_order


class ConfusionEvidence:
    """The confusion-aware model: per-frame feature ``log o``; draws ``theta (S, M)``, ``beta (S, M, M)``."""

    def __init__(self, draws: dict[str, Tensor]) -> None:
        self.num_classes = draws["theta"].shape[1]
        self.feature_size = self.num_classes
        self._normaliser, self._exponent = dirichlet_terms(
            concentrations(draws["theta"], draws["beta"])
        )  # (S, M), (S, M, M)

    def features(self, obs: Tensor) -> Tensor:
        return obs.log()

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        S, M = self._normaliser.shape
        out = torch.empty(stats.shape[0], M, dtype=stats.dtype, device=stats.device)
        step = max(1, CHUNK_ELEMENTS // (S * M))
        normaliser, exponent = (
            self._normaliser.reshape(S * M),
            self._exponent.reshape(S * M, M),
        )  # draws x classes as rows
        for start in chunks(stats.shape[0], S * M):
            rows = slice(start, start + step)
            k = stats[rows].shape[0]
            terms = block_log_lik(counts[rows].unsqueeze(-1), stats[rows], normaliser, exponent).reshape(k, S, M)
            out[rows] = logsumexp_in_order(terms.transpose(1, 2))
        return out - math.log(S)
