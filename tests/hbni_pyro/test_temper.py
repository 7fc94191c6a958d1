"""The HBNI filter's likelihood temper and its fit on labelled streams."""

from __future__ import annotations

import math

import pytest
import torch

import hbni_pyro
from hbni_pyro import HBNIFilter, fit_temper, sample_outputs
from hbni_pyro.filters import DEFAULT_GRID

from hbni_stubs import DT, THETA, DrawsPosterior


TRUE = DrawsPosterior(THETA.unsqueeze(0))


def iid_streams(num, length, seed=0):
    g = torch.Generator().manual_seed(seed)
    classes = torch.randint(0, 3, (num, 1), generator=g)
    return sample_outputs(THETA, classes.expand(num, length), g), classes[:, 0]


def repeated_streams(num, length, k, seed=0):
    """Each i.i.d. output shown ``k`` times in a row: ``length * k`` frames, perfectly correlated in blocks."""
    obs, truth = iid_streams(num, length, seed)
    return obs.repeat_interleave(k, dim=1), truth


def test_temper_one_is_the_paper_filter():
    obs, _ = iid_streams(40, 12)
    draws = THETA * torch.exp(0.4 * torch.randn(64, 3, generator=torch.Generator().manual_seed(3), dtype=DT))
    for mode in ("marginal", "plugin"):
        post = DrawsPosterior(draws)
        assert torch.equal(HBNIFilter(post, mode, temper=1.0).run(obs), HBNIFilter(post, mode).run(obs))


def test_tempered_log_evidence_matches_closed_form():
    obs, _ = iid_streams(5, 9, seed=1)
    tau = 0.35
    filt = HBNIFilter(TRUE, "plugin", temper=tau)
    n = torch.arange(1, 10, dtype=DT).view(1, -1, 1)
    offset = torch.lgamma(3 + THETA) - torch.lgamma(1 + THETA)
    log_lik = tau * (n * offset + THETA * obs.log().cumsum(1))
    torch.testing.assert_close(filt.run(obs), torch.softmax(log_lik, -1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("mode", ["marginal", "plugin"])
def test_temper_one_over_k_undoes_k_fold_repetition(mode):
    """On outputs repeated k times, temper 1/k after k*n frames is the i.i.d. filter after n outputs."""
    k = 4
    obs, _ = iid_streams(30, 6, seed=2)
    draws = THETA * torch.exp(0.3 * torch.randn(50, 3, generator=torch.Generator().manual_seed(4), dtype=DT))
    post = DrawsPosterior(draws)
    iid = HBNIFilter(post, mode).run(obs)
    tempered = HBNIFilter(post, mode, temper=1 / k).run(obs.repeat_interleave(k, dim=1))
    torch.testing.assert_close(tempered[:, k - 1 :: k], iid, rtol=0, atol=1e-10)


def test_streaming_matches_batched_with_temper():
    obs, _ = iid_streams(3, 7, seed=5)
    filt = HBNIFilter(TRUE, "plugin", temper=0.5)
    batched = filt.run(obs)
    for b in range(3):
        filt.reset()
        for n in range(7):
            assert torch.equal(filt.update(obs[b, n]), batched[b, n])


def test_fit_temper_keeps_one_on_iid_streams():
    """Under the true model the Bayes posterior (temper 1) maximises the expected log score.

    On 1500 streams the score curve near 1 is resolved well: the standard error of the score
    difference between neighbouring grid points is far below their expected gap.
    """
    obs, truth = iid_streams(1500, 15, seed=6)
    result = fit_temper(TRUE, obs, truth, mode="plugin")
    assert result.temper >= 0.85
    assert result.log_score.shape == DEFAULT_GRID.shape
    assert result.log_score[-1] > result.log_score[0]


def test_fit_temper_discounts_repeated_frames():
    """Outputs shown k times in a row carry the evidence of one: the fitted temper falls with k.

    Temper 1/k is exact at the end of each block (test above); inside a block it undercounts the
    block's first output, so the score over all prefixes settles between 1/k and 2/k.
    """
    fitted = []
    for k in (1, 2, 4, 8):
        obs, truth = repeated_streams(1000, 6, k, seed=7)
        fitted.append(fit_temper(TRUE, obs, truth, mode="plugin").temper)
        assert 1 / k - 1e-12 <= fitted[-1] <= 2 / k, (k, fitted[-1])
    assert fitted == sorted(fitted, reverse=True) and len(set(fitted)) == 4


def test_fit_temper_is_deterministic_and_takes_a_grid():
    obs, truth = repeated_streams(60, 5, 3, seed=8)
    grid = [0.2, 1 / 3, 0.5, 1.0]
    a = fit_temper(TRUE, obs, truth, mode="plugin", grid=grid)
    b = fit_temper(TRUE, obs, truth, mode="plugin", grid=grid)
    assert a.temper == b.temper and a.temper in grid
    assert torch.equal(a.log_score, b.log_score)
    assert float(a.log_score.max()) == float(a.log_score[grid.index(a.temper)])
    assert math.isfinite(float(a.log_score.min()))


def test_fit_temper_on_a_fitted_posterior():
    obs, truth = iid_streams(12, 10, seed=9)
    labels = truth.repeat_interleave(10)
    post = hbni_pyro.fit(obs.reshape(-1, 3), labels, num_chains=4, num_samples=100, warmup_steps=100, seed=0)
    result = hbni_pyro.fit_temper(post, repeated_streams(12, 10, 2, seed=9)[0], truth)
    assert 0 < result.temper <= 1


@pytest.mark.parametrize(
    "temper, error",
    [
        (0.0, ValueError),
        (-0.5, ValueError),
        (1.5, ValueError),
        (float("nan"), ValueError),
        (True, TypeError),
        ("0.5", TypeError),
        (None, TypeError),
    ],
)
def test_bad_temper_is_rejected(temper, error):
    with pytest.raises(error, match="temper: expected a"):
        HBNIFilter(TRUE, temper=temper)


def test_fit_temper_errors():
    obs, truth = iid_streams(6, 4)
    with pytest.raises(ValueError, match="grid"):
        fit_temper(TRUE, obs, truth, grid=[0.5, 1.2])
    with pytest.raises(ValueError, match="grid"):
        fit_temper(TRUE, obs, truth, grid=[])
    with pytest.raises(ValueError, match="grid"):
        fit_temper(TRUE, obs, truth, grid=[[0.5]])
    with pytest.raises(ValueError, match="true_class"):
        fit_temper(TRUE, obs, truth[:-1])
    with pytest.raises(ValueError, match="true_class"):
        fit_temper(TRUE, obs, truth.double())
    with pytest.raises(ValueError, match="true_class"):
        fit_temper(TRUE, obs, torch.full((6,), 3))
    with pytest.raises(ValueError, match="obs"):
        fit_temper(TRUE, obs[0], truth)
    with pytest.raises(ValueError, match="mode"):
        fit_temper(TRUE, obs, truth, mode="mean")
