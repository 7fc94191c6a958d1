"""Streaming class filters over classifier outputs.

Every filter here summarises a stream ``o_1, ..., o_N`` by a running sum of one per-frame
feature vector (``(M,)``) and the frame count ``N``; its class posterior is a pure function of
that sum and ``N``:

========================  ======================  ===============================================
filter                    per-frame feature        posterior after N frames
========================  ======================  ===============================================
:class:`VotingFilter`     one-hot vote             vote counts / N
:class:`MaxOfMeanFilter`  ``o``                    mean output
:class:`SSBF`             ``log o``                ``∝ p_m * prod_i o_i,m / p_m``
:class:`HBNIFilter`       ``log o``                ``∝ p_m * E_theta prod_i Dir(o_i; theta_m e_m + 1)^tau``
========================  ======================  ===============================================

The streaming path (:meth:`StreamingFilter.update`) adds one feature to the running sum;
the batched path (:meth:`StreamingFilter.run`) takes a cumulative sum over frames. Both
then call the same posterior function, so they agree exactly (``torch.cumsum`` accumulates
in frame order, like the streaming sum).

Ties: :func:`decide` returns the **lowest class index** among the maxima, and every filter's
decision (including each vote of :class:`VotingFilter`) goes through it.

Inputs pass :func:`hbni_pyro.validation.as_outputs`: bad rows raise a ``ValueError`` naming the
row, exact zeros are floored at :data:`hbni_pyro.validation.OUTPUT_FLOOR` and renormalised.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import torch
from torch import Tensor

from infra.threads import single_thread
from hbni_pyro.validation import DTYPE, as_class_prior, as_outputs

_CHUNK_ELEMENTS = 1 << 16
"""Largest number of (class, prefix, draw) log-likelihood terms the marginal HBNI filter builds at once
(512 KiB of doubles, so each chunk's passes stay in cache)."""


def decide(probs: Tensor) -> Tensor:
    """The decided label(s) of class probabilities ``(..., M)``: argmax, lowest index on ties.

    Returns a ``LongTensor`` of shape ``(...)`` (a 0-d tensor for one ``(M,)`` vector).
    """
    probs = torch.as_tensor(probs)
    if probs.dim() == 0 or probs.shape[-1] < 1:
        raise ValueError(f"probs: expected shape (..., M) with M >= 1, got {tuple(probs.shape)}")
    # torch.argmax returns the first maximal index, i.e. the lowest class index on ties.
    return probs.argmax(-1)


def _logsumexp_in_order(x: Tensor) -> Tensor:
    """``logsumexp`` over the last dim, summing in index order whatever the batch shape.

    ``torch.logsumexp`` may split a reduction across threads differently for different batch
    sizes; ``cumsum`` always adds in order, so one stream and a batch of streams agree exactly.
    """
    top = x.amax(-1, keepdim=True)
    # Terms below exp(-700) cannot change a sum that is >= 1; clamping them keeps exp and the
    # sum off the slow subnormal path.
    return top.squeeze(-1) + (x - top).clamp_min_(-700.0).exp_().cumsum(-1)[..., -1].log()


class StreamingFilter:
    """Base class: a streaming filter with a batched twin.

    Subclasses define :meth:`features` (per-frame ``(..., M) -> (..., M)``) and
    :meth:`posterior` (running feature sum and frame count ``-> (..., M)`` class probabilities).
    """

    num_classes: int

    def __init__(self, num_classes: int) -> None:
        if isinstance(num_classes, bool) or not isinstance(num_classes, int) or num_classes < 2:
            raise ValueError(f"num_classes: expected an int >= 2, got {num_classes!r}")
        self.num_classes = num_classes
        self.reset()

    def features(self, obs: Tensor) -> Tensor:
        """Per-frame feature ``(..., M)`` of validated outputs ``(..., M)``."""
        raise NotImplementedError

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        """Class probabilities ``(..., M)`` from feature sums ``(..., M)`` over ``counts (...)`` frames."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the stream seen so far."""
        self._stats = torch.zeros(self.num_classes, dtype=DTYPE)
        self._count = 0

    @property
    def frames_seen(self) -> int:
        """Number of outputs consumed since the last :meth:`reset`."""
        return self._count

    def update(self, o: Any) -> Tensor:
        """Consume one output ``o (M,)``; return the class posterior ``(M,)`` after it."""
        o = as_outputs(o, self.num_classes, name=f"o (frame {self.frames_seen + 1} of the stream)")
        if o.dim() != 1:
            raise ValueError(f"o: expected one output of shape ({self.num_classes},), got {tuple(o.shape)}")
        self._stats = self._stats + self.features(o)
        self._count += 1
        count = torch.tensor(self._count, dtype=DTYPE)
        return self.posterior(self._stats.unsqueeze(0), count.unsqueeze(0))[0]

    def statistics(self, obs: Any) -> tuple[Tensor, Tensor]:
        """Validated ``obs (B, N, M)`` -> running feature sums ``(B, N, M)`` and counts ``(N,)`` = 1..N."""
        obs = as_outputs(obs, self.num_classes, name="obs", min_dim=3)
        if obs.dim() != 3:
            raise ValueError(f"obs: expected shape (B, N, M), got {tuple(obs.shape)}")
        counts = torch.arange(1, obs.shape[1] + 1, dtype=DTYPE)
        return self.features(obs).cumsum(1), counts

    def run(self, obs: Any) -> Tensor:
        """Batched filtering: ``obs (B, N, M)`` -> posterior after each prefix ``(B, N, M)``.

        ``run(obs)[b, n]`` equals the ``(n+1)``-th :meth:`update` of a fresh stream fed ``obs[b]``.
        """
        stats, counts = self.statistics(obs)
        return self.posterior(stats, counts.expand(stats.shape[:-1]))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_classes={self.num_classes})"


class VotingFilter(StreamingFilter):
    """Majority vote: each frame votes for :func:`decide` of its output; probs = vote shares."""

    def features(self, obs: Tensor) -> Tensor:
        return torch.nn.functional.one_hot(decide(obs), self.num_classes).to(DTYPE)

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        return stats / counts.unsqueeze(-1)


class MaxOfMeanFilter(StreamingFilter):
    """Max of mean: probs = the mean output so far; the decision is its argmax."""

    def features(self, obs: Tensor) -> Tensor:
        return obs

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        return stats / counts.unsqueeze(-1)


class _LogLinearFilter(StreamingFilter):
    """Filters whose feature is ``log o`` and whose posterior is a softmax over classes."""

    def __init__(self, num_classes: int, class_prior: Any = None) -> None:
        super().__init__(num_classes)
        self.class_prior = as_class_prior(class_prior, num_classes)
        self._log_prior = self.class_prior.log()

    def features(self, obs: Tensor) -> Tensor:
        return obs.log()

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        return torch.softmax(self._log_prior + self.log_evidence(stats, counts), dim=-1)

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        """``log P(o_1:N | c = m)`` up to a constant shared by all ``m``; shape ``(..., M)``."""
        raise NotImplementedError


class SSBF(_LogLinearFilter):
    """Static-state Bayes filter: ``P_N(m) ∝ o_N,m / p_m * P_N-1(m)``, ``P_0 = p``.

    It treats each output as a (prior-divided) likelihood, so after N frames
    ``P_N(m) ∝ p_m * prod_i (o_i,m / p_m)``.
    """

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        return stats - counts.unsqueeze(-1) * self._log_prior


class _Posterior(Protocol):
    num_classes: int
    class_prior: Tensor

    def theta_draws(self) -> Tensor: ...


class HBNIFilter(_LogLinearFilter):
    """Class filter under the HBNI noise model with a fitted noise posterior.

    Args:
        posterior: anything with ``theta_draws() -> (S, M)``, ``class_prior (M,)`` and
            ``num_classes`` (an :class:`hbni_pyro.HBNIPosterior`).
        mode: ``"marginal"`` (default) averages the whole-sequence likelihood over the draws,
            ``P(c = m | o_1:N) ∝ p_m * mean_s prod_i Dir(o_i; theta_m^(s) e_m + 1)``, in log space
            with logsumexp. ``"plugin"`` uses the per-class posterior **median** of theta (the
            paper's cheaper variant; the median rather than the mean because a theta posterior
            fitted on a few outputs is right-skewed and its mean is pulled up by the tail).
            Marginal is the default because it is the Bayesian answer and the better calibrated
            one: with few training outputs theta is uncertain, and the plug-in's certainty about
            theta makes its class posteriors overconfident, so a macro-observation process that
            stops at 0.95 stops sooner and is right less often (on the paper's toy with 15
            training outputs: 98.2 % vs 96.1 % right on the noisiest class). The price: on a long
            stream the average is dominated by the few draws that fit that stream best, so after
            an unlucky fit a handful of streams stay misclassified that the plug-in gets right
            (see the ``filtering_error`` study, ``hbni.filter.mode=plugin``).
        class_prior: ``(M,)`` class prior; ``None`` takes ``posterior.class_prior``.
        num_draws: marginal mode uses at most this many draws, evenly spaced over the pooled
            draws (``None`` = all); its cost is ``O(draws)`` per frame and class.
        temper: power ``tau`` in ``(0, 1]`` on every frame's likelihood. HBNI's outputs are i.i.d.
            given the class; the frames of one camera sequence are not (the same view, light and
            background persist), so ``N`` of them carry about as much evidence as ``tau * N``
            independent outputs. ``1`` is the paper's filter; :func:`hbni_pyro.fit_temper` fits
            ``tau`` on labelled sequences.

    Both modes have the sufficient statistic ``sum_i log o_i`` and ``N``:
    ``sum_i log Dir(o_i; theta_m e_m + 1)
    = N (lgamma(M + theta_m) - lgamma(1 + theta_m)) + theta_m sum_i log o_i,m``.
    """

    MODES = ("marginal", "plugin")

    def __init__(
        self,
        posterior: _Posterior,
        mode: str = "marginal",
        class_prior: Any = None,
        *,
        num_draws: int | None = None,
        temper: float = 1.0,
    ) -> None:
        if mode not in self.MODES:
            raise ValueError(f"mode: expected one of {self.MODES}, got {mode!r}")
        if num_draws is not None and (isinstance(num_draws, bool) or not isinstance(num_draws, int) or num_draws < 1):
            raise ValueError(f"num_draws: expected a positive int or None, got {num_draws!r}")
        if isinstance(temper, bool) or not isinstance(temper, (int, float)) or not 0 < temper <= 1:
            raise ValueError(f"temper: expected a float in (0, 1], got {temper!r}")
        draws = getattr(posterior, "theta_draws", None)
        if not callable(draws):
            raise TypeError(
                f"posterior: expected an HBNIPosterior (with theta_draws()), got {type(posterior).__name__}"
            )
        theta = torch.as_tensor(draws(), dtype=DTYPE).contiguous()  # torch's median misreads stride-0 views
        if theta.dim() != 2 or theta.shape[0] < 1 or theta.shape[1] < 2:
            raise ValueError(f"posterior: theta_draws() must have shape (S, M), got {tuple(theta.shape)}")
        if not torch.isfinite(theta).all() or (theta <= 0).any():
            raise ValueError("posterior: theta draws must be finite and > 0")
        if class_prior is None:
            class_prior = getattr(posterior, "class_prior", None)
        super().__init__(theta.shape[1], class_prior)
        self.mode = mode
        self.temper = float(temper)
        if mode == "plugin":
            theta = theta.median(0).values.unsqueeze(0)
        elif num_draws is not None and num_draws < theta.shape[0]:
            theta = theta[torch.linspace(0, theta.shape[0] - 1, num_draws, dtype=DTYPE).round().long()]
        self.theta = theta
        """``(S, M)`` noise parameters used (``S = 1`` in plugin mode)."""
        offset = torch.lgamma(self.num_classes + theta) - torch.lgamma(1 + theta)
        # (M, 1, S), contiguous over draws so every (M, k, S) term tensor reduces over its inner dim
        self._offset = offset.T.contiguous().unsqueeze(1)
        self._theta = theta.T.contiguous().unsqueeze(1)

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        batch = stats.shape[:-1]
        stats = self.temper * stats.reshape(-1, self.num_classes).T.contiguous().unsqueeze(-1)  # (M, K, 1)
        counts = self.temper * counts.expand(batch).reshape(1, -1, 1)  # (1, K, 1)
        offset, theta = self._offset, self._theta
        num_draws = theta.shape[-1]
        chunk = max(1, _CHUNK_ELEMENTS // (num_draws * self.num_classes))
        out = torch.empty(self.num_classes, stats.shape[1], dtype=DTYPE)
        with single_thread():  # torch splits even small cumsums across threads; the hand-offs cost more
            for start in range(0, stats.shape[1], chunk):
                end = start + chunk
                terms = torch.addcmul(counts[:, start:end] * offset, theta, stats[:, start:end])  # (M, k, S)
                out[:, start:end] = _logsumexp_in_order(terms)
        return (out - math.log(num_draws)).T.reshape(*batch, self.num_classes)

    def __repr__(self) -> str:
        return (f"HBNIFilter(num_classes={self.num_classes}, mode={self.mode!r}, draws={self.theta.shape[0]}, "
                f"temper={self.temper:g})")
