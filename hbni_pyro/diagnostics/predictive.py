"""Posterior predictive checks of a fitted noise model on a user's held-out classifier outputs.

:func:`predictive_check` runs the macro-observation process (a filter
on the posterior, stopped at ``threshold`` or at the frame budget) on every held-out stream, and the same
process on streams simulated from the posterior (:meth:`~hbni_pyro.HBNIPosterior.sample_streams`), as many
per held-out stream as ``simulations`` says, each of the same class and length. It then compares, per class:

==================  =====================================================  ===============================
check               observed quantity                                      test against the simulation
==================  =====================================================  ===============================
``emitted``         share of emitted labels that are right                 exact binomial test
``overall``         share of streams whose label at the stop is right      exact binomial test
``timeouts``        share of streams that time out                         exact binomial test
``frames``          frames used by each stream (a timeout: all it had)     two-sample Kolmogorov-Smirnov
``calibration``     mean of ``right - confidence`` at each stream's stop   two-sample z test
==================  =====================================================  ===============================

Streams: with ``sequence_ids`` each sequence is one stream, its frames in the order given; without them
every output is its own one-frame stream (so ``frames`` is constant and the checks reduce to one-frame
decisions). Without labels only label-free quantities are checked, on all streams pooled, their classes
simulated from the posterior's class prior: ``timeouts``, ``frames`` and ``confidence`` (the confidence at
the stop, Kolmogorov-Smirnov).

The tests are :mod:`hbni_infra.stats`'s (scipy's exact binomial and two-sample Kolmogorov-Smirnov tests, a
two-sample z test). The binomial tests take the simulated rate as exact; its Monte Carlo error is
``1 / simulations`` of the observed one's variance. Kolmogorov-Smirnov on frame counts (discrete) is conservative. :meth:`PredictiveCheck.passed`
corrects for the number of tests (Bonferroni), so a model that is right fails with probability at most ``alpha``.
The comparison is with the average over the posterior's draws: a held-out set far larger than the training set
can reject an honest but uncertain posterior.

Devices: the streams are simulated on the posterior's device and filtered on the filter's; the result, a report,
holds CPU tensors.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from hbni_pyro.diagnostics.reliability import Reliability, reliability
from hbni_pyro.filters.macro import MacroObservationBatch, MacroObservationProcess
from hbni_pyro.filters.streaming import HBNIFilter, StreamingFilter
from hbni_pyro.validation import DTYPE, as_labels, as_outputs, as_sequence_ids
from hbni_infra.checks import as_int, as_probability, as_seed
from hbni_infra.files import atomic_write_bytes
from hbni_infra.optional import require
from hbni_infra.stats import binomial_test, ks_test, z_test
from hbni_infra.streams import torch_generator

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from hbni_pyro.posterior.posterior import HBNIPosterior

LABELLED_CHECKS = ("emitted", "overall", "timeouts", "frames", "calibration")
UNLABELLED_CHECKS = ("timeouts", "frames", "confidence")


class _Outcomes:
    """Per-stream results of the process: ``label``, ``right`` (bool, or ``None`` unlabelled), ``confidence``,
    ``frames``, ``timed_out``, and ``truth`` (``(B,)``), concatenated over groups of streams onto the CPU."""

    def __init__(self, batches: list[MacroObservationBatch], truths: list[Tensor]) -> None:
        self.label = torch.cat([b.label for b in batches]).cpu()
        self.confidence = torch.cat([b.confidence for b in batches]).cpu()
        self.frames = torch.cat([b.frames_used for b in batches]).cpu()
        self.timed_out = torch.cat([b.timed_out for b in batches]).cpu()
        self.truth = torch.cat(truths).cpu()
        self.right = self.label == self.truth

    def select(self, rows: Tensor) -> dict[str, Tensor]:
        return {k: getattr(self, k)[rows] for k in ("label", "confidence", "frames", "timed_out", "truth", "right")}


@dataclass
class PredictiveCheck:
    """The outcome of :func:`predictive_check`.

    Attributes:
        table: one row per class (``class`` is its name or index), or one row ``"all"`` without labels: observed
            and predicted values of each check (``emitted_accuracy`` / ``predicted_emitted_accuracy``, ...) and
            its p-value ``p_<check>``; ``streams``, ``emitted`` counts.
        p_values: ``"<class>: <check>" -> p`` for every test that could run (none on an empty set).
        labelled: whether labels were given (otherwise only label-free checks ran).
        threshold, max_frames: the process's settings (``max_frames`` ``None``: each stream's length).
        observed, predicted: reliability diagrams of the confidence at each stream's stop (labelled only).
        frames: ``"observed"`` / ``"predicted"`` -> frames used per stream ``(B,)``.
    """

    table: list[dict[str, Any]]
    p_values: dict[str, float]
    labelled: bool
    threshold: float
    max_frames: int | None
    observed: Reliability | None = None
    predicted: Reliability | None = None
    frames: dict[str, Tensor] = field(default_factory=dict)

    @property
    def min_p_value(self) -> float:
        return min(self.p_values.values(), default=float("nan"))

    def failures(self, alpha: float = 0.05) -> dict[str, float]:
        """The tests whose p-value is below ``alpha / len(p_values)`` (Bonferroni)."""
        alpha = as_probability("alpha", alpha, allow_zero=False)
        bound = alpha / max(1, len(self.p_values))
        return {k: p for k, p in self.p_values.items() if p < bound}

    def passed(self, alpha: float = 0.05) -> bool:
        """No test rejects at family-wise level ``alpha`` (Bonferroni over all p-values)."""
        return not self.failures(alpha)

    def report(self) -> str:
        """The table as text, one line per class."""
        lines = [
            f"posterior predictive check at threshold {self.threshold:g}"
            + ("" if self.labelled else " (no labels: label-free checks only)")
        ]
        checks = LABELLED_CHECKS if self.labelled else UNLABELLED_CHECKS
        for row in self.table:
            parts = [f"{row['class']}: {row['streams']} streams"]
            for name in checks:
                key = _VALUE_KEYS[name]
                parts.append(f"{key} {row[key]:.3g} vs {row['predicted_' + key]:.3g} (p={row['p_' + name]:.3g})")
            lines.append(", ".join(parts))
        return "\n".join(lines)

    __str__ = report

    def figure(self) -> "Figure":
        """A matplotlib Figure: the reliability diagram (labelled only) and frames-to-threshold histograms,
        observed against predicted (needs matplotlib: the ``analysis`` extra)."""
        figure = require("matplotlib.figure", "analysis", "PredictiveCheck.figure()")
        fig = figure.Figure(figsize=(10 if self.labelled else 5, 4), layout="constrained")
        axes = fig.subplots(1, 2 if self.labelled else 1, squeeze=False)[0]
        if self.labelled and self.observed is not None and self.predicted is not None:
            ax = axes[0]
            ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")  # perfect calibration
            for name, r in (("observed", self.observed), ("predicted", self.predicted)):
                used = r.count > 0
                ax.plot(
                    r.confidence[used].numpy(), r.accuracy[used].numpy(), marker="o", label=f"{name} (ECE {r.ece:.3f})"
                )
            ax.set(
                xlabel="confidence at the stop",
                ylabel="share right",
                title="reliability",
                xlim=(float(self.observed.edges[0]), 1),
                ylim=(0, 1.02),
            )
            ax.legend()
        ax = axes[-1]
        top = int(max(int(v.max()) for v in self.frames.values()))
        bins = torch.arange(0.5, top + 1.5).numpy()
        for name, v in self.frames.items():
            ax.hist(v.numpy(), bins=bins, density=True, histtype="step", lw=1.5, label=name)
        ax.set(xlabel="frames used", ylabel="share of streams", title=f"frames to threshold {self.threshold:g}")
        ax.legend()
        return fig

    def save_figure(self, path: str | os.PathLike) -> Path:
        """Write :meth:`figure` as a PNG to ``path``, atomically; returns the path."""
        buffer = io.BytesIO()
        self.figure().savefig(buffer, format="png", dpi=100)
        return atomic_write_bytes(path, buffer.getvalue())


_VALUE_KEYS = {
    "emitted": "emitted_accuracy",
    "overall": "overall_accuracy",
    "timeouts": "timeout_rate",
    "frames": "mean_frames",
    "calibration": "calibration_gap",
    "confidence": "mean_confidence",
}


def predictive_check(
    posterior: "HBNIPosterior",
    outputs: Any,
    labels: Any = None,
    sequence_ids: Any = None,
    *,
    threshold: float = 0.95,
    max_frames: int | None = None,
    seed: int = 0,
    simulations: int = 20,
    filter: StreamingFilter | None = None,
) -> PredictiveCheck:
    """Posterior predictive checks of ``posterior`` on held-out outputs (see the module's docstring).

    Args:
        posterior: the fitted :class:`hbni_pyro.HBNIPosterior`.
        outputs: ``(N, M)`` classifier outputs, frames of all streams.
        labels: ``(N,)`` true class of each output (one per sequence), or ``None`` for label-free checks.
        sequence_ids: ``(N,)`` integer sequence of each output (a sequence is one stream, in the order given);
            ``None``: every output is its own one-frame stream.
        threshold: the process stops once its top posterior probability reaches it, in ``(0, 1]``.
        max_frames: frame budget of a stream (``None``: all its frames).
        seed: seed of the simulation (same seed, same result).
        simulations: simulated streams per held-out stream (>= 1).
        filter: the streaming filter (``None``: ``HBNIFilter(posterior)``).
    """
    num_classes = posterior.num_classes
    outputs = as_outputs(outputs, num_classes, name="outputs")
    if outputs.dim() != 2 or outputs.shape[0] < 1:
        raise ValueError(f"outputs: expected shape (N, {num_classes}) with N >= 1, got {tuple(outputs.shape)}")
    n = outputs.shape[0]
    threshold = as_probability("threshold", threshold, allow_zero=False)
    max_frames = None if max_frames is None else as_int("max_frames", max_frames, minimum=1)
    seed = as_seed("seed", seed)
    simulations = as_int("simulations", simulations, minimum=1)
    if filter is None:
        filter = HBNIFilter(posterior)
    elif not isinstance(filter, StreamingFilter):
        raise TypeError(f"filter: expected a StreamingFilter or None, got {type(filter).__name__}")
    if filter.num_classes != num_classes:
        raise ValueError(f"filter: expected {num_classes} classes like the posterior, got {filter.num_classes}")
    ids = torch.arange(n) if sequence_ids is None else as_sequence_ids(sequence_ids, n)
    streams = list(torch.argsort(ids, stable=True).split(torch.bincount(ids).tolist()))  # frames in the order given
    truth = None if labels is None else _stream_labels(as_labels(labels, n, num_classes), streams)
    g = torch_generator(seed, posterior.device)
    if truth is None:
        truth_sim = torch.multinomial(posterior.class_prior.to(DTYPE), len(streams) * simulations, True, generator=g)
        truth_sim = truth_sim.cpu()
        truth = torch.full((len(streams),), -1, dtype=torch.long)
    else:
        truth_sim = truth.repeat_interleave(simulations)
    observed, predicted = _run(
        posterior, filter, outputs, streams, truth, truth_sim, simulations, threshold, max_frames, g
    )
    labelled = labels is not None
    groups = (
        [(c, observed.truth == c, predicted.truth == c) for c in range(num_classes)]
        if labelled
        else [
            (
                None,
                torch.ones_like(observed.truth, dtype=torch.bool),
                torch.ones_like(predicted.truth, dtype=torch.bool),
            )
        ]
    )
    names = posterior.class_names
    table, p_values = [], {}
    for c, obs_rows, sim_rows in groups:
        if not obs_rows.any():
            continue
        name = "all" if c is None else (names[c] if names else str(c))
        row = _row(observed.select(obs_rows), predicted.select(sim_rows), labelled)
        row["class"] = name
        table.append(row)
        checks = LABELLED_CHECKS if labelled else UNLABELLED_CHECKS
        p_values.update({f"{name}: {k}": row[f"p_{k}"] for k in checks if not math.isnan(row[f"p_{k}"])})
    low = 1.0 / num_classes
    return PredictiveCheck(
        table,
        p_values,
        labelled,
        threshold,
        max_frames,
        observed=reliability(observed.confidence, observed.right, low=low) if labelled else None,
        predicted=reliability(predicted.confidence, predicted.right, low=low) if labelled else None,
        frames={"observed": observed.frames, "predicted": predicted.frames},
    )


def _stream_labels(labels: Tensor, streams: list[Tensor]) -> Tensor:
    """One label per stream: every output of a stream must carry the same known class."""
    first = torch.stack([rows[0] for rows in streams])
    out = labels[first]
    if (out < 0).any():
        raise ValueError(
            f"labels: entry {int(first[out < 0][0])} is -1 (unknown); predictive_check needs every label, or labels=None"
        )
    lengths = torch.tensor([len(rows) for rows in streams])
    mixed = labels[torch.cat(streams)] != out.repeat_interleave(lengths)
    if mixed.any():
        k = int(torch.arange(len(streams)).repeat_interleave(lengths)[mixed][0])
        raise ValueError(
            f"labels: the outputs of sequence {k} carry different classes {labels[streams[k]].unique().tolist()}"
        )
    return out


def _run(
    posterior: "HBNIPosterior",
    filter: StreamingFilter,
    outputs: Tensor,
    streams: list[Tensor],
    truth: Tensor,
    truth_sim: Tensor,
    simulations: int,
    threshold: float,
    max_frames: int | None,
    g: torch.Generator,
) -> tuple[_Outcomes, _Outcomes]:
    """Run the process on the held-out streams and on their simulated twins, grouped by stream length."""
    lengths = torch.tensor([len(s) for s in streams])
    sim_lengths = lengths.repeat_interleave(simulations)
    obs_batches, obs_truth, sim_batches, sim_truth = [], [], [], []
    for length in lengths.unique().tolist():
        process = MacroObservationProcess(filter, threshold, length if max_frames is None else min(length, max_frames))
        picks = (lengths == length).nonzero().squeeze(-1)
        obs_batches.append(process.run_batch(torch.stack([outputs[streams[k]] for k in picks.tolist()])))
        obs_truth.append(truth[picks])
        rows = (sim_lengths == length).nonzero().squeeze(-1)
        classes = truth_sim[rows]
        sim = torch.empty(len(rows), length, posterior.num_classes, dtype=DTYPE, device=posterior.device)
        for c in classes.unique().tolist():
            at = (classes == c).nonzero().squeeze(-1)
            sim[at] = posterior.sample_streams(c, len(at), length, generator=g)
        sim_batches.append(process.run_batch(sim))
        sim_truth.append(classes)
    return _Outcomes(obs_batches, obs_truth), _Outcomes(sim_batches, sim_truth)


def _row(obs: dict[str, Tensor], sim: dict[str, Tensor], labelled: bool) -> dict[str, Any]:
    """Observed and predicted values of each check on one group of streams, with p-values."""
    emitted, sim_emitted = ~obs["timed_out"], ~sim["timed_out"]
    row: dict[str, Any] = {"streams": len(obs["frames"]), "emitted": int(emitted.sum())}
    _binomial(row, "timeouts", obs["timed_out"], sim["timed_out"])
    row["mean_frames"], row["predicted_mean_frames"] = (
        float(obs["frames"].to(DTYPE).mean()),
        float(sim["frames"].to(DTYPE).mean()),
    )
    row["p_frames"] = ks_test(obs["frames"], sim["frames"])
    if labelled:
        _binomial(row, "emitted", obs["right"][emitted], sim["right"][sim_emitted])
        _binomial(row, "overall", obs["right"], sim["right"])
        gap, sim_gap = obs["right"].to(DTYPE) - obs["confidence"], sim["right"].to(DTYPE) - sim["confidence"]
        row["calibration_gap"], row["predicted_calibration_gap"] = float(gap.mean()), float(sim_gap.mean())
        row["p_calibration"] = z_test(gap, sim_gap)
    else:
        row["mean_confidence"], row["predicted_mean_confidence"] = (
            float(obs["confidence"].mean()),
            float(sim["confidence"].mean()),
        )
        row["p_confidence"] = ks_test(obs["confidence"], sim["confidence"])
    return row


def _binomial(row: dict[str, Any], name: str, hits: Tensor, sim_hits: Tensor) -> None:
    """Observed share of ``hits``, the simulated share, and the exact binomial test of one against the other."""
    key = _VALUE_KEYS[name]
    k, n, m = int(hits.sum()), len(hits), len(sim_hits)
    rate = float(sim_hits.to(DTYPE).mean()) if m else float("nan")
    row[key], row["predicted_" + key] = (k / n if n else float("nan")), rate
    if not n or not m:
        row["p_" + name] = float("nan")
        return
    p = min(max(rate, 0.5 / m), 1 - 0.5 / m)  # a simulated 0 or 1 is a rate below 1 / m, not an impossibility
    row["p_" + name] = binomial_test(k, n, p)
