"""Reliability diagrams, expected calibration error and the macro-observation threshold checks."""

import math

import pytest
import torch
from hbni_stubs import DT, THETA, DrawsPosterior

from hbni_pyro import (
    Fold,
    HBNIFilter,
    MacroObservationProcess,
    StaticStateBayesFilter,
    binomial_stderr,
    cross_fit,
    fit_stop_threshold,
    fit_stop_unlabelled,
    reliability,
    sample_outputs,
    stream_reliability,
    threshold_checks,
)
from hbni_pyro.diagnostics import assert_calibrated


def test_reliability_by_hand():
    conf = torch.tensor([0.55, 0.65, 0.95, 0.91, 0.99])
    right = torch.tensor([True, False, True, True, False])
    r = reliability(conf, right, num_bins=5, low=0.5)
    assert r.count.tolist() == [1, 1, 0, 0, 3]
    torch.testing.assert_close(r.confidence[[0, 1, 4]], torch.tensor([0.55, 0.65, (0.95 + 0.91 + 0.99) / 3], dtype=DT))
    torch.testing.assert_close(r.accuracy[[0, 1, 4]], torch.tensor([1.0, 0.0, 2 / 3], dtype=DT))
    assert r.confidence[2].isnan() and r.accuracy[3].isnan()
    expected = (0.45 + 0.65 + 3 * abs(0.95 - 2 / 3)) / 5
    assert r.ece == pytest.approx(expected)
    with pytest.raises(ValueError, match="confidence, correct"):
        reliability(conf, right[:2])


def test_a_filter_that_knows_the_truth_is_calibrated():
    """HBNI with the true theta on i.i.d. toy streams: its ECE over every prefix is within a few
    hundredths (Monte Carlo noise of 600 x 10 correlated prefixes)."""
    g = torch.Generator().manual_seed(0)
    truth = torch.randint(0, 3, (600,), generator=g)
    streams = sample_outputs(THETA, truth[:, None].expand(600, 10), g)
    r = stream_reliability(HBNIFilter(DrawsPosterior(THETA.unsqueeze(0))), streams, truth)
    assert r.ece < 0.03 and r.count.sum() == 6000
    bad = stream_reliability(
        StaticStateBayesFilter(3), streams, truth
    )  # SSBF treats each output as a likelihood: overconfident
    assert bad.ece > r.ece
    for threshold in (0.9, 0.95, 0.99):  # and its emitted labels keep the promise of each threshold
        assert_calibrated(
            MacroObservationProcess(HBNIFilter(DrawsPosterior(THETA.unsqueeze(0))), threshold, 10), streams, truth
        )


def test_threshold_checks_agree_with_the_process():
    g = torch.Generator().manual_seed(1)
    truth = torch.randint(0, 3, (200,), generator=g)
    streams = sample_outputs(THETA, truth[:, None].expand(200, 8), g)
    f = HBNIFilter(DrawsPosterior(THETA.unsqueeze(0)))
    checks = threshold_checks(f, streams, truth, thresholds=(0.9, 0.999999), max_frames=4)
    for t, row in checks.items():
        batch = MacroObservationProcess(f, float(t), 4).run_batch(streams)
        emitted = ~batch.timed_out
        assert row["emitted"] == int(emitted.sum())
        assert row["emitted_accuracy"] == pytest.approx(float((batch.label == truth)[emitted].double().mean()))
        assert row["timeout_rate"] == pytest.approx(float(batch.timed_out.double().mean()))
        assert row["mean_frames"] == pytest.approx(float(batch.frames_used.double().mean()))
        assert row["emitted_stderr"] == pytest.approx(binomial_stderr(row["emitted_accuracy"], row["emitted"]))
        assert row["timeout_stderr"] == pytest.approx(binomial_stderr(row["timeout_rate"], 200))
        assert row["frames_stderr"] == pytest.approx(float(batch.frames_used.double().std()) / 200**0.5)
    assert checks["0.999999"]["timeout_rate"] > checks["0.9"]["timeout_rate"]
    assert assert_calibrated(MacroObservationProcess(f, 0.9, 4), streams, truth) == checks["0.9"]
    assert binomial_stderr(0.5, 0) != binomial_stderr(0.5, 0)  # NaN with no trials


def wilson_lower(right: int, n: int, z: float = 1.0) -> float:
    """The Wilson score interval's lower end by hand: ``(p + z^2/2n - z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)``,
    0 with no trials."""
    if n == 0:
        return 0.0
    p = right / n
    return (p + z * z / (2 * n) - z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)


def test_stop_threshold_is_the_lowest_that_keeps_the_promise():
    """On streams where the filter knows the truth (i.i.d. frames, true theta), the chosen stop is the lowest
    candidate whose emitted accuracy's Wilson lower bound reaches the target, by brute force over the grid; a stop
    at it keeps the promise and takes no more frames than stopping at the target itself."""
    g = torch.Generator().manual_seed(2)
    truth = torch.randint(0, 3, (400,), generator=g)
    streams = sample_outputs(THETA, truth[:, None].expand(400, 12), g)
    f = HBNIFilter(DrawsPosterior(THETA.unsqueeze(0)))
    fit = fit_stop_threshold(f, streams, truth, 0.9)
    emitted = []
    for t, acc, lower in zip(fit.grid, fit.emitted_accuracy, fit.lower):
        row = threshold_checks(f, streams, truth, [t])[f"{t:g}"]
        emitted.append(row["emitted"])
        assert acc == row["emitted_accuracy"]
        assert lower == pytest.approx(wilson_lower(round(acc * row["emitted"]), row["emitted"]))
    assert fit.stop == min(t for t, lower in zip(fit.grid, fit.lower) if lower >= 0.9)
    checks = threshold_checks(f, streams, truth, [0.9], stops={0.9: fit.stop})["0.9"]
    assert checks["stop"] == fit.stop and checks["emitted_accuracy"] >= 0.9
    assert checks["mean_frames"] <= threshold_checks(f, streams, truth, [0.9])["0.9"]["mean_frames"]
    at_zero = fit_stop_threshold(f, streams, truth, 0.9, z=0.0)  # zero standard errors: the emitted accuracy itself
    assert at_zero.lower == [wilson_lower(round(a * n), n, z=0.0) for a, n in zip(at_zero.emitted_accuracy, emitted)]
    assert at_zero.stop == min(t for t, acc in zip(at_zero.grid, at_zero.emitted_accuracy) if acc >= 0.9) <= fit.stop
    # a promise no candidate keeps: the promise itself
    assert fit_stop_threshold(StaticStateBayesFilter(3), streams, truth, 0.99, grid=[0.5, 0.6]).stop == 0.99
    with pytest.raises(ValueError, match="grid"):
        fit_stop_threshold(f, streams, truth, 0.9, grid=[0.1, 0.2])
    with pytest.raises(ValueError, match="target"):
        fit_stop_threshold(f, streams, truth, 0.0)


def test_cross_fit_holds_out_each_sequence_once():
    """Each fold's filter is fitted on the other folds' sequences only, and every sequence is held out exactly
    once, with its class as its truth."""
    C, S, N, M = 3, 5, 4, 3
    outputs = torch.arange(C * S * N * M, dtype=DT).reshape(C, S, N, M)
    seen = []

    def fit(train: torch.Tensor, k: int) -> StaticStateBayesFilter:
        seen.append((k, train))
        return StaticStateBayesFilter(M)

    folds = cross_fit(fit, outputs, folds=2)
    assert [k for k, _ in seen] == [0, 1] and [train.shape[1] for _, train in seen] == [2, 3]
    held = {tuple(s.flatten().tolist()): int(t) for f in folds for s, t in zip(f.streams, f.truth)}
    assert len(held) == C * S
    for c in range(C):
        for s in range(S):
            assert held[tuple(outputs[c, s].flatten().tolist())] == c
            k = s % 2
            assert not (seen[k][1] == outputs[c, s]).all(-1).all(-1).any()  # never fitted on its held-out fold
    with pytest.raises(ValueError, match="folds"):
        cross_fit(fit, outputs, folds=1)
    with pytest.raises(ValueError, match="outputs"):
        cross_fit(fit, outputs, folds=6)


def test_stop_on_folds_pools_their_counts():
    """Folds that share one filter give exactly the stop, accuracies, bounds, frames and timeouts of that filter
    on all their streams at once (the pooled counts are the counts of the union)."""
    g = torch.Generator().manual_seed(3)
    truth = torch.randint(0, 3, (300,), generator=g)
    streams = sample_outputs(THETA, truth[:, None].expand(300, 10), g)
    f = HBNIFilter(DrawsPosterior(THETA.unsqueeze(0)))
    whole = fit_stop_threshold(f, streams, truth, 0.9)
    folds = [Fold(f, streams[i::3], truth[i::3]) for i in range(3)]
    pooled = fit_stop_threshold(folds, None, None, 0.9)
    assert pooled.stop == whole.stop and pooled.grid == whole.grid
    for a, b in zip(pooled[3:], whole[3:]):
        torch.testing.assert_close(torch.tensor(a), torch.tensor(b), equal_nan=True)
    with pytest.raises(TypeError, match="filter"):
        fit_stop_threshold(folds, streams, truth, 0.9)
    with pytest.raises(TypeError, match="filter"):
        fit_stop_threshold([], None, None, 0.9)
    with pytest.raises(ValueError, match="z"):
        fit_stop_threshold(f, streams, truth, 0.9, z=-1.0)


def _sequence_place(seed: int) -> tuple[dict[str, torch.Tensor], float]:
    """Sequence-model parameters of 3 classes whose looks lie close (a place where the stop matters), and the
    AR(1) correlation of a stream's frames."""
    from hbni_pyro.distributions.prior import HyperPrior
    from hbni_pyro.models.sequence.program import look_prior_mean
    from hbni_pyro.models.sequence import draw_prior

    params = {k: v[0] for k, v in draw_prior(HyperPrior(), 3, 1, torch.Generator().manual_seed(seed)).items()}
    params["loc"] = look_prior_mean(3, 0.8)
    return params, 0.5


def _true_filter(params: dict[str, torch.Tensor], rho: float) -> HBNIFilter:
    from hbni_pyro.posterior.posterior import posterior_from_samples
    from hbni_pyro.distributions.prior import HyperPrior

    samples = {k: v.expand((1, 1) + v.shape).clone() for k, v in params.items()}
    posterior = posterior_from_samples(samples, torch.full((3,), 1 / 3), HyperPrior(), "sequence")
    posterior.frame_correlation = rho
    return HBNIFilter(posterior)


def _sequence_streams(params, rho, n, g) -> tuple[torch.Tensor, torch.Tensor]:
    from hbni_pyro import sample_sequences

    truth = torch.arange(n) % 3
    return sample_sequences(params["loc"], params["between"], params["within"], truth, 20, g, rho), truth


def test_unlabelled_stop_is_unbiased_and_honest_under_the_true_model():
    """Streams simulated from a sequence model with correlated frames and that model's own filter: at every
    candidate stop, the accuracy that ``fit_stop_unlabelled`` estimates from 600 unlabelled streams lies within 4
    binomial standard errors of the emitted labels' actual accuracy on them, and at the stop it picks for 0.9 the
    labels of 900 fresh streams are right at least 0.9 less 2 standard errors."""
    params, rho = _sequence_place(0)
    g = torch.Generator().manual_seed(1)
    f = _true_filter(params, rho)
    streams, truth = _sequence_streams(params, rho, 600, g)
    fit = fit_stop_unlabelled(f, streams, 0.9)
    actual = threshold_checks(f, streams, truth, fit.grid)
    for t, estimate in zip(fit.grid, fit.emitted_accuracy):
        row = actual[f"{t:g}"]
        assert abs(estimate - row["emitted_accuracy"]) <= 4 * binomial_stderr(estimate, row["emitted"]), t
    assert fit.stop <= 0.9 and fit.lower[fit.grid.index(0.5)] < 0.9  # a place where the choice matters
    fresh, fresh_truth = _sequence_streams(params, rho, 600, g)
    kept = threshold_checks(f, fresh, fresh_truth, [0.9], stops={0.9: fit.stop})["0.9"]
    assert kept["emitted_accuracy"] >= 0.9 - 2 * kept["emitted_stderr"]


def test_unlabelled_stop_refuses_bad_input():
    params, rho = _sequence_place(0)
    f = _true_filter(params, rho)
    streams, _ = _sequence_streams(params, rho, 6, torch.Generator().manual_seed(0))
    with pytest.raises(TypeError, match="filter"):
        fit_stop_unlabelled(params, streams, 0.9)
    with pytest.raises(ValueError, match="streams: expected"):
        fit_stop_unlabelled(f, streams[0], 0.9)
    with pytest.raises(ValueError, match="target"):
        fit_stop_unlabelled(f, streams, 1.5)
    with pytest.raises(ValueError, match="grid"):
        fit_stop_unlabelled(f, streams, 0.9, grid=[0.2])
    fit = fit_stop_unlabelled(f, streams, 0.9, grid=[0.99], z=0.0)
    assert fit.grid == [0.99] and fit.target == 0.9
    with pytest.raises(ValueError, match="labels: expected 6 integer classes"):
        fit_stop_unlabelled(f, streams, 0.9, labels=torch.zeros(5, dtype=torch.long))


def test_known_labels_stand_for_themselves():
    """With every label known, the unlabelled stop is the labelled one (without its Wilson rounding of counts)."""
    params, rho = _sequence_place(0)
    f = _true_filter(params, rho)
    streams, truth = _sequence_streams(params, rho, 120, torch.Generator().manual_seed(2))
    known = fit_stop_unlabelled(f, streams, 0.9, labels=truth)
    labelled = fit_stop_threshold(f, streams, truth, 0.9)
    assert known.stop == labelled.stop
    torch.testing.assert_close(torch.tensor(known.emitted_accuracy), torch.tensor(labelled.emitted_accuracy))
