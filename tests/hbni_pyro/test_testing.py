"""The assertions of hbni_pyro.diagnostics.testing: they pass on honest processes and models, and fail with the figures."""

import pytest
import torch
from hbni_stubs import THETA, DrawsPosterior

import hbni_pyro
from hbni_pyro import HBNIFilter, MacroObservationProcess, StaticStateBayesFilter, sample_outputs
from hbni_pyro.diagnostics import assert_calibrated, assert_predictive_check_fails, assert_predictive_check_passes


def toy_streams(n=600, frames=10, seed=0, theta=THETA):
    g = torch.Generator().manual_seed(seed)
    truth = torch.randint(0, 3, (n,), generator=g)
    return sample_outputs(theta, truth[:, None].expand(n, frames), g), truth


def test_assert_calibrated_passes_on_the_true_model_and_returns_the_figures():
    streams, truth = toy_streams()
    process = MacroObservationProcess(HBNIFilter(DrawsPosterior(THETA.unsqueeze(0))), 0.95, 10)
    row = assert_calibrated(process, streams, truth)
    assert row["emitted"] > 500 and row["emitted_accuracy"] >= 0.95 - 3 * (0.95 * 0.05 / row["emitted"]) ** 0.5


def test_assert_calibrated_fails_on_an_overconfident_filter_and_quotes_the_figures():
    """SSBF on outputs 5x noisier than its outputs claim: its emitted labels are right 94 % of the time at threshold 0.99 (466 emitted)."""
    streams, truth = toy_streams(theta=THETA / 5)
    process = MacroObservationProcess(StaticStateBayesFilter(3), 0.99, 10)
    with pytest.raises(
        AssertionError, match=r"emitted labels right 0\.\d+ \(\d+/\d+ emitted, \d+ timeouts\) < 0\.99 - slack 0"
    ):
        assert_calibrated(process, streams, truth)
    assert_calibrated(process, streams, truth, slack=0.5)  # a slack that large forgives it
    assert_calibrated(process, streams, truth, 0.9)  # it does keep a lesser promise


def test_assert_calibrated_with_no_label_emitted():
    streams, truth = toy_streams(n=20, frames=1)
    process = MacroObservationProcess(HBNIFilter(DrawsPosterior(THETA.unsqueeze(0))), 1.0, 1)
    with pytest.raises(AssertionError, match="no label emitted: all 20 streams timed out"):
        assert_calibrated(process, streams, truth)


def test_assert_calibrated_argument_errors():
    streams, truth = toy_streams(n=20, frames=2)
    process = MacroObservationProcess(StaticStateBayesFilter(3), 0.9, 2)
    with pytest.raises(TypeError, match="process"):
        assert_calibrated(StaticStateBayesFilter(3), streams, truth)
    with pytest.raises(ValueError, match="slack"):
        assert_calibrated(process, streams, truth, slack=-0.1)
    with pytest.raises(ValueError, match="threshold"):
        assert_calibrated(process, streams, truth, 1.2)
    with pytest.raises(ValueError, match="z"):
        assert_calibrated(process, streams, truth, z=-1.0)


@pytest.fixture(scope="module")
def posterior():
    g = torch.Generator().manual_seed(0)
    classes = torch.arange(3).repeat_interleave(40)
    return hbni_pyro.fit(
        sample_outputs(THETA, classes, g),
        classes,
        num_chains=4,
        num_samples=100,
        warmup_steps=300,
        seed=0,
        progress=False,
    )


def held_out(posterior, source, streams=30, frames=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    outputs = torch.cat([source(c, streams, frames, g) for c in range(3)]).reshape(-1, 3)
    return (
        outputs,
        torch.arange(3).repeat_interleave(streams * frames),
        torch.arange(3 * streams).repeat_interleave(frames),
    )


def test_assert_check_passes_and_fails(posterior):
    own = held_out(posterior, lambda c, n, f, g: posterior.sample_streams(c, n, f, generator=g))
    noisier = held_out(posterior, lambda c, n, f, g: sample_outputs(THETA / 5, torch.full((n, f), c), g))
    assert assert_predictive_check_passes(posterior, *own, alpha=0.01).passed(0.01)
    with pytest.raises(AssertionError, match=r"posterior predictive check passed at alpha 0.01, smallest p-value"):
        assert_predictive_check_fails(posterior, *own, alpha=0.01)
    assert not assert_predictive_check_fails(posterior, *noisier, alpha=0.01).passed(0.01)
    with pytest.raises(
        AssertionError, match=r"check failed at alpha 0.01 \(Bonferroni over 15 tests\): .*1: emitted p="
    ):
        assert_predictive_check_passes(posterior, *noisier, alpha=0.01)
    with pytest.raises(ValueError, match="threshold"):
        assert_predictive_check_passes(posterior, *own, threshold=2.0)
