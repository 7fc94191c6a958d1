"""How much a stream's outputs so far support each class, averaged over the sequence-aware model's posterior draws.

The look terms are those of :mod:`hbni_pyro.models.sequence.looks`; the surface is that of
:class:`~hbni_pyro.models.paper.evidence.PaperEvidence`. On the CPU the average is compiled
(:mod:`hbni_pyro.models.sequence.evidence_numba`).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from hbni_pyro.distributions.density import ilr
from hbni_pyro.distributions.draws import CHUNK_ELEMENTS, chunks, logsumexp_in_order
from hbni_pyro.models.sequence import evidence_numba
from hbni_pyro.models.sequence.looks import look_basis, look_log_marginal, look_variance, within_log_prob


_KEPT_VARIANCES = 32
"""Frame counts whose look variances :class:`SequenceEvidence` keeps (a filter meets one per frame; 2000 draws of
six classes take 0.6 MB a count)."""


class SequenceEvidence:
    """The sequence-aware model: per-frame features ``y = ilr(o)`` and ``y y^T`` (flattened); draws
    ``loc (S, M, d)``, ``between (S, M, d, d)``, ``within (S, d, d)``. Each sequence's look is
    integrated out exactly: the evidence of ``n`` frames is that of their mean look under
    ``N(loc_c, between_c + within / n)`` times the frames' scatter term under ``within`` (the same
    for every class, but not for every draw).

    With ``correlation`` ``rho`` (:mod:`hbni_pyro.models.sequence.correlation`), the frames scatter about their look as
    an AR(1) series. Their Prais-Winsten transform ``u_1 = sqrt(1 - rho^2) y_1``, ``u_t = y_t - rho y_{t-1}``
    has independent rows ``u_t ~ N(a_t mu, (1 - rho^2) within)`` with ``a_1 = sqrt(1 - rho^2)`` and
    ``a_t = 1 - rho``, so the features become ``a_t u_t`` and ``u_t u_t^T`` (frame ``t``'s depend on frame
    ``t - 1``: :attr:`lagged`), the mean look their weighted mean, and ``n`` frames count as
    ``n_eff = 1 + (n - 1)(1 - rho) / (1 + rho)`` in ``between_c + within / n_eff``.
    """

    def __init__(self, draws: dict[str, Tensor], correlation: float = 0.0) -> None:
        loc, between, within = draws["loc"], draws["between"], draws["within"]
        S, self.num_classes, self.dim = loc.shape
        self.feature_size = self.dim + self.dim**2
        self.correlation = float(correlation)
        self.lagged = self.correlation != 0.0
        """Whether a frame's features depend on the frame before it (time is the second-to-last axis)."""
        self._basis, self._lam, self._logdet = look_basis(
            between, within.unsqueeze(1)
        )  # (S, M, d, d), (S, M, d), (S, 1)
        self._basis_loc = (self._basis @ loc.unsqueeze(-1)).squeeze(-1)  # (S, M, d)
        self._within_prec = torch.linalg.inv(within).reshape(S, -1)  # (S, d d)
        self._compiled = None  # on the CPU: the tables of evidence_numba.log_evidence, draws last
        if loc.device.type == "cpu" and loc.dtype == torch.float64:
            self._compiled = tuple(
                t.contiguous().numpy()
                for t in (
                    self._basis.permute(1, 2, 3, 0),
                    self._basis_loc.permute(1, 2, 0),
                    self._within_prec.T.reshape(self.dim, self.dim, S),
                    self._logdet.reshape(S),
                )
            )
        self._variances: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_variances": {}}  # a copy sent to another process recomputes what it needs

    def _variance(self, n_eff: float) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~hbni_pyro.models.sequence.looks.look_variance` at the effective count ``n_eff``, ``(M, d, S)``, and
        the sum of its logs, ``(M, S)``, computed once per count: the logs cost more than the rest of a block's
        evidence."""
        kept = self._variances.get(n_eff)
        if kept is None:
            if len(self._variances) >= _KEPT_VARIANCES:
                self._variances.clear()
            var, log_var = look_variance(n_eff, self._lam)
            kept = self._variances[n_eff] = (
                var.permute(1, 2, 0).contiguous().numpy(),
                log_var.T.contiguous().numpy(),
            )
        return kept

    def features(self, obs: Tensor) -> Tensor:
        """``(..., M) -> (..., d + d^2)``; when :attr:`lagged`, ``obs (..., N, M)`` holds streams from their first
        frame."""
        y = ilr(obs)
        if self.lagged:
            rho, edge = self.correlation, math.sqrt(1.0 - self.correlation**2)
            u = torch.cat([edge * y[..., :1, :], y[..., 1:, :] - rho * y[..., :-1, :]], -2)
            weighted = torch.cat([edge * u[..., :1, :], (1.0 - rho) * u[..., 1:, :]], -2)
            return torch.cat([weighted, (u.unsqueeze(-1) * u.unsqueeze(-2)).flatten(-2)], -1)
        return torch.cat([y, (y.unsqueeze(-1) * y.unsqueeze(-2)).flatten(-2)], -1)

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        S, d = self._basis.shape[0], self.dim
        rho = self.correlation
        weight = (1.0 - rho**2) + (counts - 1.0) * (1.0 - rho) ** 2  # sum_t a_t^2 (= n without correlation)
        mean_y = stats[:, :d] / weight.unsqueeze(-1)
        scatter = stats[:, d:] - weight[:, None] * (mean_y.unsqueeze(-1) * mean_y.unsqueeze(-2)).flatten(-2)  # (K, d d)
        effective = weight / (1.0 - rho**2)  # n_eff
        # the AR(1) density's terms that depend on neither class nor draw (0 without correlation)
        shift = -0.5 * d * ((weight / counts).log() + (counts - 2.0) * math.log(1.0 - rho**2))
        if self._compiled is not None and stats.device.type == "cpu" and stats.dtype == torch.float64:
            out = self._compiled_evidence(mean_y, scatter, counts, effective)
        else:
            out = self._torch_evidence(mean_y, scatter, counts, effective)
        return out - math.log(S) + shift.unsqueeze(-1)

    def _compiled_evidence(self, mean_y: Tensor, scatter: Tensor, counts: Tensor, effective: Tensor) -> Tensor:
        """``log sum_s`` of the draws' terms ``(K, M)`` by :func:`.evidence_numba.log_evidence`, the blocks of each
        effective count together."""
        out = torch.empty(len(counts), self.num_classes, dtype=torch.float64)
        values, group = torch.unique(effective, return_inverse=True)
        scatter = scatter.reshape(-1, self.dim, self.dim)
        for u, n_eff in enumerate(values.tolist()):
            rows = (group == u).nonzero().squeeze(1)
            out[rows] = torch.from_numpy(
                evidence_numba.log_evidence(
                    mean_y[rows].numpy(),
                    scatter[rows].numpy(),
                    counts[rows].numpy(),
                    *self._variance(n_eff),
                    *self._compiled,
                    1.0 / (1.0 - self.correlation**2),
                )
            )
        return out

    def _torch_evidence(self, mean_y: Tensor, scatter: Tensor, counts: Tensor, effective: Tensor) -> Tensor:
        """``log sum_s`` of the draws' terms ``(K, M)`` with torch, a chunk of blocks at a time (on any device)."""
        S, M, d = self._basis.shape[0], self.num_classes, self.dim
        rho = self.correlation
        flat_basis = self._basis.reshape(S * M * d, d)
        out = torch.empty(mean_y.shape[0], M, dtype=mean_y.dtype, device=mean_y.device)
        step = max(1, CHUNK_ELEMENTS // (S * M * d))
        for start in chunks(mean_y.shape[0], S * M * d):
            rows = slice(start, start + step)
            k = mean_y[rows].shape[0]
            resid = (flat_basis @ mean_y[rows].T).reshape(S, M, d, k).permute(
                3, 0, 1, 2
            ) - self._basis_loc  # (k, S, M, d)
            n, n_eff = counts[rows][:, None, None], effective[rows][:, None, None]
            # tr(W^-1 scatter) by one matmul, over (1 - rho^2) W
            trace = (scatter[rows] @ self._within_prec.T).unsqueeze(-1) / (1.0 - rho**2)  # (k, S, 1)
            terms = look_log_marginal(n_eff, resid, self._lam, self._logdet) + within_log_prob(
                n, trace, self._logdet, d
            )
            out[rows] = logsumexp_in_order(terms.transpose(1, 2))
        return out
