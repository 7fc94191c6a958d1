"""Streaming class filters over classifier outputs.

Every filter here summarises a stream ``o_1, ..., o_N`` by a running sum of one per-frame
feature vector (``(M,)``) and the frame count ``N``; its class posterior is a pure function of
that sum and ``N``:

===============================  ======================  ===============================================
filter                           per-frame feature       posterior after N frames
===============================  ======================  ===============================================
:class:`VotingFilter`            one-hot vote            vote counts / N
:class:`MaxOfMeanFilter`         ``o``                   mean output
:class:`StaticStateBayesFilter`  ``log o``               ``∝ p_m * prod_i o_i,m / p_m`` (SSBF)
:class:`HBNIFilter`              ``log o`` (or ``ilr o``  ``∝ p_m * E_draws p(o_1:N | c = m)^tau`` under the fitted noise model
                                 and its square)
===============================  ======================  ===============================================

The calibrated peer (``make_filter("calibrated")``) is SSBF on calibrated frames ``q_i``
(:mod:`hbni_pyro.filters.frame_calibration`), its feature ``log q`` and every frame's evidence weighed by a
temper ``tau``: ``∝ p_m * prod_i (q_i,m / p_m)^tau``.

The streaming path (:meth:`StreamingFilter.update`) adds one feature to the running sum;
the batched path (:meth:`StreamingFilter.run`) takes a cumulative sum over frames. Both
then call the same posterior function, so they agree exactly (``torch.cumsum`` accumulates
in frame order, like the streaming sum).

Ties: :func:`decide` returns the **lowest class index** among the maxima, and every filter's
decision (including each vote of :class:`VotingFilter`) goes through it.

Inputs pass :func:`hbni_pyro.validation.as_outputs`: bad rows raise a ``ValueError`` naming the
row, exact zeros are floored at :data:`hbni_pyro.validation.OUTPUT_FLOOR` and renormalised.

Devices: a filter runs on its :attr:`StreamingFilter.device`, the ``device=`` it was built with
(default: the CPU, or for an :class:`HBNIFilter` the device of its posterior's draws). Inputs are
moved there and the beliefs returned there. On ``meta`` (shapes only) the value checks are skipped
and :meth:`~StreamingFilter.update` and :meth:`~StreamingFilter.run` return shapes.
"""

from __future__ import annotations

import copy
from typing import Any, Protocol

import torch
from torch import Tensor

from hbni_pyro.models import noise_model
from hbni_pyro.validation import DTYPE, as_class_prior, as_outputs, check_same_classes, has_values
from hbni_infra.checks import as_device, as_float, as_int
from hbni_infra.threads import single_thread


def decide(probs: Tensor) -> Tensor:
    """The decided label(s) of class probabilities ``(..., M)``: argmax, lowest index on ties.

    Returns a ``LongTensor`` of shape ``(...)`` (a 0-d tensor for one ``(M,)`` vector).
    """
    probs = torch.as_tensor(probs)
    if probs.dim() == 0 or probs.shape[-1] < 1:
        raise ValueError(f"probs: expected shape (..., M) with M >= 1, got {tuple(probs.shape)}")
    # torch.argmax returns the first maximal index, i.e. the lowest class index on ties.
    return probs.argmax(-1)


class StreamingFilter:
    """Base class: a streaming filter with a batched twin.

    Subclasses define :meth:`features` (per-frame ``(..., M) -> (..., F)``) and
    :meth:`posterior` (running feature sum and frame count ``-> (..., M)`` class probabilities);
    ``F = feature_size`` (``M`` unless a subclass says otherwise). A subclass whose :attr:`lagged` is true
    computes a frame's feature from it and the frame before: its :meth:`features` takes streams
    ``(..., N, M)`` from their first frame. ``class_names`` are the classes' names in
    column order when the filter knows them (an HBNI filter: its posterior's), else ``None``. ``device`` is
    where it runs: a ``str`` or ``torch.device``.
    """

    num_classes: int
    device: torch.device
    class_names: tuple[str, ...] | None = None

    @property
    def feature_size(self) -> int:
        return self.num_classes

    @property
    def lagged(self) -> bool:
        """Whether a frame's feature depends on the frame before it."""
        return False

    def __init__(self, num_classes: int, device: str | torch.device = "cpu") -> None:
        self.num_classes = as_int("num_classes", num_classes, minimum=2)
        self.device = as_device("device", device)
        self.reset()

    def features(self, obs: Tensor) -> Tensor:
        """Per-frame feature ``(..., M)`` of validated outputs ``(..., M)``."""
        raise NotImplementedError

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        """Class probabilities ``(..., M)`` from feature sums ``(..., F)`` over ``counts (...)`` frames."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the stream seen so far."""
        self._stats = torch.zeros(self.feature_size, dtype=DTYPE, device=self.device)
        self._count = 0
        self._last: Tensor | None = None

    @property
    def frames_seen(self) -> int:
        """Number of outputs consumed since the last :meth:`reset`."""
        return self._count

    def update(self, o: Any) -> Tensor:
        """Consume one output ``o (M,)``; return the class posterior ``(M,)`` after it, on :attr:`device`."""
        o = as_outputs(o, self.num_classes, name=f"o (frame {self.frames_seen + 1} of the stream)")
        if o.dim() != 1:
            raise ValueError(f"o: expected one output of shape ({self.num_classes},), got {tuple(o.shape)}")
        o = o.to(self.device)
        if self.lagged:  # the feature of o as the last frame of (previous frame, o)
            window = o.unsqueeze(0) if self._last is None else torch.stack([self._last, o])
            self._stats = self._stats + self.features(window)[-1]
            self._last = o
        else:
            self._stats = self._stats + self.features(o)
        self._count += 1
        count = torch.full((1,), self._count, dtype=DTYPE, device=self.device)
        return self.posterior(self._stats.unsqueeze(0), count)[0]

    def statistics(self, obs: Any) -> tuple[Tensor, Tensor]:
        """Validated ``obs (B, N, M)`` -> running feature sums ``(B, N, F)`` and counts ``(N,)`` = 1..N, on
        :attr:`device`."""
        obs = as_outputs(obs, self.num_classes, name="obs", min_dim=3)
        if obs.dim() != 3:
            raise ValueError(f"obs: expected shape (B, N, M), got {tuple(obs.shape)}")
        counts = torch.arange(1, obs.shape[1] + 1, dtype=DTYPE, device=self.device)
        return self.features(obs.to(self.device)).cumsum(1), counts

    def run(self, obs: Any) -> Tensor:
        """Batched filtering: ``obs (B, N, M)`` -> posterior after each prefix ``(B, N, M)``, on :attr:`device`.

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

    def __init__(self, num_classes: int, class_prior: Any = None, device: str | torch.device = "cpu") -> None:
        super().__init__(num_classes, device)
        self.class_prior = as_class_prior(class_prior, num_classes).to(self.device)
        self._log_prior = self.class_prior.log()

    def features(self, obs: Tensor) -> Tensor:
        return obs.log()

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        return torch.softmax(self._log_prior + self.log_evidence(stats, counts), dim=-1)

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        """``log P(o_1:N | c = m)`` up to a constant shared by all ``m``; shape ``(..., M)``."""
        raise NotImplementedError


class StaticStateBayesFilter(_LogLinearFilter):
    """Static-state Bayes filter (SSBF, ``make_filter("ssbf")``): ``P_N(m) ∝ o_N,m / p_m * P_N-1(m)``, ``P_0 = p``.

    It treats each output as a (prior-divided) likelihood, so after N frames
    ``P_N(m) ∝ p_m * prod_i (o_i,m / p_m)``.

    The calibrated peer (``make_filter("calibrated")``) is the same filter on calibrated frames: with a
    :class:`~hbni_pyro.filters.frame_calibration.FrameCalibration` ``calibration``, each output ``o_i`` is replaced by
    ``q_i = calibration(o_i)`` (fitted on labelled calibration frames), and a ``temper`` ``tau`` in ``(0, 1]``
    weighs every frame's evidence, ``P_N(m) ∝ p_m * prod_i (q_i,m / p_m)^tau``: ``N`` correlated frames of one
    sequence count as ``tau * N`` independent ones (:func:`hbni_pyro.fit_temper` fits ``tau`` on labelled
    sequences, as for HBNI's frame-level models).
    """

    def __init__(
        self,
        num_classes: int,
        class_prior: Any = None,
        device: str | torch.device = "cpu",
        *,
        calibration: Any = None,
        temper: float = 1.0,
    ) -> None:
        super().__init__(num_classes, class_prior, device)
        self.temper = as_float("temper", temper, 0.0, 1.0, low_open=True)
        if calibration is not None:
            if not callable(getattr(calibration, "log_probs", None)):
                raise TypeError(f"calibration: expected a FrameCalibration, got {type(calibration).__name__}")
            if calibration.num_classes != self.num_classes:
                raise ValueError(
                    f"calibration: expected a map of {self.num_classes} classes, got {calibration.num_classes}"
                )
            calibration = calibration.to(self.device)
            self.class_names = calibration.class_names
        self.calibration = calibration

    def features(self, obs: Tensor) -> Tensor:
        return obs.log() if self.calibration is None else self.calibration.log_probs(obs)

    def log_evidence(self, stats: Tensor, counts: Tensor) -> Tensor:
        return self.temper * (stats - counts.unsqueeze(-1) * self._log_prior)

    def tempered(self, temper: float) -> StaticStateBayesFilter:
        """The same filter with evidence weight ``temper``."""
        return StaticStateBayesFilter(
            self.num_classes, self.class_prior, self.device, calibration=self.calibration, temper=temper
        )

    def __repr__(self) -> str:
        kind = "none" if self.calibration is None else self.calibration.kind
        return f"StaticStateBayesFilter(num_classes={self.num_classes}, calibration={kind}, temper={self.temper:g})"


class _Posterior(Protocol):
    num_classes: int
    class_prior: Tensor

    def theta_draws(self) -> Tensor: ...


class HBNIFilter(StreamingFilter):
    """Class filter under a fitted HBNI noise model (any variant of :data:`hbni_pyro.models.NOISE_MODELS`).

    Args:
        posterior: an :class:`hbni_pyro.HBNIPosterior` (its ``model`` picks the likelihood), or
            anything with ``theta_draws() -> (S, M)``, ``class_prior (M,)`` and ``num_classes``
            (taken as the paper's model).
        mode: ``"marginal"`` (default) averages the whole-sequence likelihood over the draws,
            ``P(c = m | o_1:N) ∝ p_m * mean_s p(o_1:N | c = m, draw s)``, in log space with
            logsumexp. ``"plugin"`` uses one point estimate: the per-class posterior **median** of
            theta (and of beta) for the frame-level models (the paper's cheaper variant; the median
            rather than the mean because a theta posterior fitted on a few outputs is right-skewed
            and its mean is pulled up by the tail), the posterior mean of the looks' means and
            covariances for the sequence model. Marginal is the default because it is the Bayesian
            answer and the better calibrated one: with few training outputs theta is uncertain, and
            the plug-in's certainty about theta makes its class posteriors overconfident, so a
            macro-observation process that stops at 0.95 stops sooner and is right less often (the
            ``macro_observation`` study measures both modes on the paper's toy).
            The price: on a long stream the average is dominated by the few draws that fit that
            stream best, so after an unlucky fit a handful of streams stay misclassified that the
            plug-in gets right (see the ``filtering_error`` study, ``hbni.filter.mode=plugin``).
        class_prior: ``(M,)`` class prior; ``None`` takes ``posterior.class_prior``.
        num_draws: marginal mode uses at most this many draws, evenly spaced over the pooled
            draws; its cost is ``O(draws)`` per frame and class. ``None`` = the model's
            spec's ``filter_draws`` (:mod:`hbni_pyro.models`): all draws, except at most 2000 under the
            sequence model, whose cost per draw is ``M - 1`` times the paper's (``benchmarks/bench_fit_scale.py``
            times a frame's update against its 2 ms floor).
        temper: power ``tau`` in ``(0, 1]`` on every frame's likelihood (all statistics scaled by
            ``tau``). The frame-level models treat outputs as i.i.d.; the frames of one camera
            sequence are not (the same view, light and background persist), so ``N`` of them carry
            about as much evidence as ``tau * N`` independent outputs. ``1`` is the model's own
            filter; :func:`hbni_pyro.fit_temper` fits ``tau`` on labelled sequences. The sequence
            model integrates each sequence's look out instead and needs no temper.
        frame_correlation: under the sequence model, the lag-1 correlation in ``(-1, 1)`` of a stream's frames
            about its look (:mod:`hbni_pyro.models.sequence.correlation`): ``N`` correlated frames then count as
            ``1 + (N - 1)(1 - rho) / (1 + rho)`` about their look. ``None`` takes the posterior's
            ``frame_correlation`` (0 when it has none); 0 treats the frames as exchangeable.
        device: where the filter runs (the draws are moved there); ``None``: the device of the posterior's draws.

    The frame-level models have the sufficient statistic ``sum_i log o_i`` and ``N``; the sequence
    model ``sum_i ilr(o_i)``, ``sum_i ilr(o_i) ilr(o_i)^T`` and ``N``.
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
        frame_correlation: float | None = None,
        device: str | torch.device | None = None,
    ) -> None:
        if mode not in self.MODES:
            raise ValueError(f"mode: expected one of {self.MODES}, got {mode!r}")
        num_draws = None if num_draws is None else as_int("num_draws", num_draws, minimum=1)
        temper = as_float("temper", temper, 0.0, 1.0, low_open=True)
        spec = noise_model(getattr(posterior, "model", "paper"))
        if frame_correlation is None:
            frame_correlation = getattr(posterior, "frame_correlation", 0.0)
        rho = as_float("frame_correlation", frame_correlation, -1.0, 1.0, low_open=True, high_open=True)
        if rho != 0.0 and not spec.correlated_frames:
            raise ValueError(f"frame_correlation: the {spec.name!r} model's filter takes none, got {rho}")
        if rho != 0.0 and temper != 1.0:  # the temper scales counts, which the AR(1) weights are not linear in
            raise ValueError(
                f"temper: a filter with frame_correlation {rho:g} counts correlated frames itself; expected "
                f"temper 1 (or frame_correlation=0), got {temper:g}"
            )
        self.frame_correlation = rho
        self.model = spec.name
        self.class_names = getattr(posterior, "class_names", None)
        draws = _checked_draws(posterior)
        device = next(iter(draws.values())).device if device is None else as_device("device", device)
        draws = {k: v.to(device) for k, v in draws.items()}
        if class_prior is None:
            class_prior = getattr(posterior, "class_prior", None)
        num_classes = spec.num_classes(draws, lead=1)
        self.class_prior = as_class_prior(class_prior, num_classes).to(device)
        self._log_prior = self.class_prior.log()
        self.mode = mode
        self.temper = float(temper)
        num_draws = spec.filter_draws if num_draws is None else num_draws
        if mode == "plugin":
            draws = spec.point_estimate(draws)
        elif num_draws is not None and num_draws < len(next(iter(draws.values()))):
            total = len(next(iter(draws.values())))
            picks = torch.linspace(0, total - 1, num_draws, dtype=DTYPE, device=device).round().long()
            draws = {k: v[picks] for k, v in draws.items()}
        self.draws = draws
        """The draws used, site -> ``(S, ...)`` (``S = 1`` in plugin mode)."""
        self._evidence = spec.evidence(draws, correlation=rho) if spec.correlated_frames else spec.evidence(draws)
        super().__init__(num_classes, device)

    def tempered(self, temper: float) -> HBNIFilter:
        """The same filter (its draws, mode and prior) with likelihood temper ``temper``."""
        temper = as_float("temper", temper, 0.0, 1.0, low_open=True)
        if self.frame_correlation != 0.0 and temper != 1.0:
            raise ValueError(
                f"temper: a filter with frame_correlation {self.frame_correlation:g} counts correlated frames "
                f"itself; expected temper 1, got {temper:g}"
            )
        out = copy.copy(self)
        out.temper = temper
        out.reset()
        return out

    @property
    def theta(self) -> Tensor:
        """``(S, M)`` noise parameters used by a frame-level model (``S = 1`` in plugin mode)."""
        return self.draws["theta"]

    @property
    def feature_size(self) -> int:
        return self._evidence.feature_size

    @property
    def lagged(self) -> bool:
        return getattr(self._evidence, "lagged", False)

    def features(self, obs: Tensor) -> Tensor:
        return self._evidence.features(obs)

    def posterior(self, stats: Tensor, counts: Tensor) -> Tensor:
        batch = stats.shape[:-1]
        stats = self.temper * stats.reshape(-1, stats.shape[-1])
        counts = self.temper * counts.expand(batch).reshape(-1)
        with single_thread():  # torch splits even small cumsums across threads; the hand-offs cost more
            log_ev = self._evidence.log_evidence(stats, counts)
        return torch.softmax(self._log_prior + log_ev, -1).reshape(*batch, self.num_classes)

    def __repr__(self) -> str:
        return (
            f"HBNIFilter(model={self.model!r}, num_classes={self.num_classes}, mode={self.mode!r}, "
            f"draws={len(next(iter(self.draws.values())))}, temper={self.temper:g}"
            + (f", frame_correlation={self.frame_correlation:.3f})" if self.frame_correlation else ")")
        )


def _checked_draws(posterior: Any) -> dict[str, Tensor]:
    """The posterior's pooled draws as float64, checked: finite, concentrations > 0, covariances SPD (values
    are not checked on ``meta``).

    An object with only ``theta_draws()`` (``(S, M)``) stands for a paper's-model posterior."""
    if not callable(getattr(posterior, "draws", None)):
        fn = getattr(posterior, "theta_draws", None)
        if not callable(fn):
            raise TypeError(
                f"posterior: expected an HBNIPosterior (with theta_draws()), got {type(posterior).__name__}"
            )
        draws = {"theta": fn()}
    else:
        draws = posterior.draws()
    draws = {
        k: torch.as_tensor(v, dtype=DTYPE).contiguous() for k, v in draws.items()
    }  # torch's median misreads stride-0 views
    if "theta" in draws:
        theta = draws["theta"]
        if theta.dim() != 2 or theta.shape[0] < 1 or theta.shape[1] < 2:
            raise ValueError(f"posterior: theta_draws() must have shape (S, M), got {tuple(theta.shape)}")
    if not has_values(next(iter(draws.values()))):
        return draws
    for name, x in draws.items():
        if not torch.isfinite(x).all():
            raise ValueError(f"posterior: {name} draws must be finite")
    if "theta" in draws and ((draws["theta"] <= 0).any() or ("beta" in draws and (draws["beta"] <= 0).any())):
        raise ValueError("posterior: theta draws must be finite and > 0")
    for name in ("between", "within"):
        if name in draws and torch.linalg.cholesky_ex(draws[name]).info.any():
            raise ValueError(f"posterior: every {name} draw must be a positive-definite covariance")
    return draws


FILTERS = ("hbni", "calibrated", "ssbf", "max_of_mean", "voting")


def make_filter(
    name: str,
    posterior: Any = None,
    *,
    num_classes: int | None = None,
    device: str | torch.device | None = None,
    **options: Any,
) -> StreamingFilter:
    """The streaming filter called ``name`` (one of :data:`FILTERS`).

    ``"hbni"`` is :class:`HBNIFilter` on ``posterior`` with ``options`` (``mode``, ``temper``, ``num_draws``,
    ``class_prior``, ``frame_correlation``); ``"calibrated"``, the calibrated peer, is :class:`StaticStateBayesFilter`
    on calibrated frames (options ``calibration``, a :class:`~hbni_pyro.FrameCalibration`, required, ``temper`` and
    ``class_prior``); the baselines ``"ssbf"``, ``"max_of_mean"`` and ``"voting"`` need only
    ``num_classes`` (default: the posterior's, or the calibration's; given a posterior, they take its class
    names), and ``"ssbf"`` takes a ``class_prior``.
    ``device``: where the filter runs (``None``: the posterior's device, else the CPU).
    """
    if name not in FILTERS:
        raise ValueError(f"name: expected one of {FILTERS}, got {name!r}")
    if name == "hbni":
        if posterior is None:
            raise ValueError("posterior: the 'hbni' filter needs a fitted posterior, got None")
        return HBNIFilter(posterior, device=device, **options)
    if name == "calibrated":
        calibration = options.get("calibration")
        if calibration is None:
            raise ValueError("calibration: the 'calibrated' filter needs a fitted FrameCalibration, got None")
        if num_classes is None:
            num_classes = getattr(calibration, "num_classes", None)
    if num_classes is None:
        if posterior is None:
            raise ValueError(f"num_classes: the {name!r} filter needs num_classes or a posterior")
        num_classes = posterior.num_classes
    allowed = {"ssbf": {"class_prior"}, "calibrated": {"class_prior", "calibration", "temper"}}.get(name, set())
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise TypeError(f"options: the {name!r} filter takes {sorted(allowed) or 'no options'}, got {unknown}")
    if device is None:
        device = getattr(posterior, "device", "cpu")
    if name == "calibrated":
        baseline = StaticStateBayesFilter(num_classes, device=device, **options)
    else:
        baseline = {"ssbf": StaticStateBayesFilter, "max_of_mean": MaxOfMeanFilter, "voting": VotingFilter}[name](
            num_classes, device=device, **options
        )
    names = getattr(posterior, "class_names", None)
    if names is not None and len(names) == baseline.num_classes:
        check_same_classes(baseline.class_names, names, "the calibration", "posterior")
        baseline.class_names = tuple(names)
    return baseline
