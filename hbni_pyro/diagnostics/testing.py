"""Assertions for a test suite: is a macro-observation process honest, does a fitted posterior pass its checks?

Each raises ``AssertionError`` with the figures behind the verdict, so a failing test says by how much.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch

from hbni_pyro.diagnostics.predictive import PredictiveCheck, predictive_check
from hbni_pyro.filters.macro import MacroObservationProcess
from hbni_pyro.filters.stopping import binomial_stderr, threshold_checks
from hbni_infra.checks import as_float, as_probability

if TYPE_CHECKING:
    from hbni_pyro.posterior.posterior import HBNIPosterior


def assert_calibrated(
    process: MacroObservationProcess,
    streams: Any,
    classes: Any,
    threshold: float | None = None,
    *,
    slack: float = 0.0,
    z: float = 3.0,
) -> dict[str, Any]:
    """Assert that ``process``'s emitted labels on ``streams (B, N, M)`` of true ``classes (B,)`` are right at least
    ``threshold - slack`` of the time, less ``z`` binomial standard errors of that rate over the emitted labels.

    Args:
        threshold: the promised accuracy (``None``: the process's threshold).
        slack: accuracy given up on purpose (a model known to be slightly optimistic), in ``[0, 1]``.
        z: standard errors of margin (3: a calibrated process fails about once in 740 runs).

    Returns:
        the :func:`hbni_pyro.threshold_checks` row (``emitted_accuracy``, ``emitted``, ``timeout_rate``, ...).
    """
    if not isinstance(process, MacroObservationProcess):
        raise TypeError(f"process: expected a MacroObservationProcess, got {type(process).__name__}")
    threshold = process.threshold if threshold is None else as_probability("threshold", threshold)
    slack = as_probability("slack", slack)
    z = as_float("z", z, 0.0)
    streams = torch.as_tensor(streams)
    row = threshold_checks(process.filter, streams, torch.as_tensor(classes), (process.threshold,), process.max_frames)[
        f"{process.threshold:g}"
    ]
    n, acc = row["emitted"], row["emitted_accuracy"]
    if n == 0:
        raise AssertionError(
            f"no label emitted: all {len(streams)} streams timed out at threshold {process.threshold:g}"
        )
    target = threshold - slack
    margin = z * binomial_stderr(min(max(target, 0.0), 1.0), n)
    if acc < target - margin:
        raise AssertionError(
            f"emitted labels right {acc:.4f} ({round(acc * n)}/{n} emitted, {len(streams) - n} timeouts) < "
            f"{threshold:g} - slack {slack:g} - {z:g} x stderr {margin / z if z else 0.0:.4f} = {target - margin:.4f}"
        )
    return row


def assert_predictive_check_passes(
    posterior: "HBNIPosterior",
    outputs: Any,
    labels: Any = None,
    sequence_ids: Any = None,
    *,
    alpha: float = 0.01,
    **options: Any,
) -> PredictiveCheck:
    """Assert that :func:`hbni_pyro.predictive_check` finds no misfit at family-wise level ``alpha``; ``options`` go
    to it (``threshold``, ``max_frames``, ``seed``, ``simulations``, ``filter``). Returns the result."""
    result = predictive_check(posterior, outputs, labels, sequence_ids, **options)
    failures = result.failures(alpha)
    if failures:
        raise AssertionError(
            f"posterior predictive check failed at alpha {alpha:g} (Bonferroni over {len(result.p_values)} tests): "
            + ", ".join(f"{k} p={p:.3g}" for k, p in failures.items())
            + "\n"
            + result.report()
        )
    return result


def assert_predictive_check_fails(
    posterior: "HBNIPosterior",
    outputs: Any,
    labels: Any = None,
    sequence_ids: Any = None,
    *,
    alpha: float = 0.01,
    **options: Any,
) -> PredictiveCheck:
    """Assert that :func:`hbni_pyro.predictive_check` rejects the posterior at family-wise level ``alpha`` (the
    outputs come from a different noise). Returns the result."""
    result = predictive_check(posterior, outputs, labels, sequence_ids, **options)
    if result.passed(alpha):
        raise AssertionError(
            f"posterior predictive check passed at alpha {alpha:g}, smallest p-value {result.min_p_value:.3g} "
            f">= {alpha:g} / {len(result.p_values)} tests\n" + result.report()
        )
    return result
