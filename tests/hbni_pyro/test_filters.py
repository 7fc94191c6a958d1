"""Streaming filters: hand-computed values, brute-force HBNI, streaming == batched, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats
import torch

from hbni_pyro import (
    FILTERS,
    OUTPUT_FLOOR,
    FrameCalibration,
    HBNIFilter,
    HBNIPosterior,
    MaxOfMeanFilter,
    StaticStateBayesFilter,
    VotingFilter,
    decide,
    make_filter,
    sample_outputs,
)
from hbni_pyro.filters import StreamingFilter

from hbni_stubs import DT, THETA, DrawsPosterior


def scattered_draws(num, seed=1):
    g = torch.Generator().manual_seed(seed)
    return THETA * torch.exp(0.5 * torch.randn(num, 3, generator=g, dtype=DT))


def toy_streams(num, length, seed=0):
    g = torch.Generator().manual_seed(seed)
    classes = torch.randint(0, 3, (num, 1), generator=g).expand(num, length)
    return sample_outputs(THETA, classes, g), classes[:, 0]


def all_filters():
    post = DrawsPosterior(scattered_draws(257))
    return [
        VotingFilter(3),
        MaxOfMeanFilter(3),
        StaticStateBayesFilter(3),
        StaticStateBayesFilter(3, class_prior=[0.5, 0.3, 0.2]),
        HBNIFilter(post),
        HBNIFilter(post, "plugin"),
        HBNIFilter(post, class_prior=[0.2, 0.3, 0.5], num_draws=50),
    ]


# -- decisions and ties -------------------------------------------------------------------------


def test_decide_breaks_ties_towards_the_lowest_class_index():
    assert int(decide(torch.tensor([0.4, 0.4, 0.2]))) == 0
    assert int(decide(torch.tensor([0.2, 0.4, 0.4]))) == 1
    assert int(decide(torch.tensor([1 / 3, 1 / 3, 1 / 3]))) == 0
    batch = torch.tensor([[[0.1, 0.45, 0.45], [0.5, 0.2, 0.3]]])
    assert decide(batch).tolist() == [[1, 0]]
    with pytest.raises(ValueError, match="probs"):
        decide(torch.tensor(0.5))


# -- hand-computed values -----------------------------------------------------------------------

OBS = [[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.4, 0.4, 0.2]]


def test_voting_counts_votes_with_ties_to_the_lowest_index():
    probs = VotingFilter(3).run(torch.tensor([OBS], dtype=DT))[0]
    expected = [[1, 0, 0], [0.5, 0.5, 0], [2 / 3, 1 / 3, 0]]  # the third frame ties 0 and 1 -> votes 0
    torch.testing.assert_close(probs, torch.tensor(expected, dtype=DT), rtol=0, atol=1e-15)
    assert decide(probs).tolist() == [0, 0, 0]


def test_max_of_mean_is_the_running_mean():
    probs = MaxOfMeanFilter(3).run(torch.tensor([OBS], dtype=DT))[0]
    expected = [[0.6, 0.3, 0.1], [0.4, 0.4, 0.2], [0.4, 0.4, 0.2]]
    torch.testing.assert_close(probs, torch.tensor(expected, dtype=DT), rtol=0, atol=1e-12)
    assert decide(probs).tolist() == [0, 0, 0]


def test_ssbf_matches_the_recursion_by_hand():
    prior = [0.5, 0.25, 0.25]
    probs = StaticStateBayesFilter(3, class_prior=prior).run(torch.tensor([OBS], dtype=DT))[0]
    belief = list(prior)
    for n, o in enumerate(OBS):
        belief = [o[m] / prior[m] * belief[m] for m in range(3)]
        total = sum(belief)
        belief = [b / total for b in belief]
        torch.testing.assert_close(probs[n], torch.tensor(belief, dtype=DT), rtol=1e-12, atol=0)


def _brute_force_hbni(obs, draws, prior):
    """p_m * mean_s prod_i Dir(o_i; theta_m^(s) e_m + 1), with scipy densities and no log-space tricks."""
    obs, draws = np.asarray(obs), np.asarray(draws)
    M = obs.shape[1]
    out = []
    for n in range(1, len(obs) + 1):
        weights = []
        for m in range(M):
            lik = []
            for theta in draws:
                alpha = np.ones(M)
                alpha[m] += theta[m]
                lik.append(np.prod([scipy.stats.dirichlet.pdf(o, alpha) for o in obs[:n]]))
            weights.append(prior[m] * np.mean(lik))
        out.append(np.array(weights) / np.sum(weights))
    return np.array(out)


def test_hbni_marginal_matches_brute_force_over_draws():
    draws = scattered_draws(7)
    prior = [0.2, 0.3, 0.5]
    obs, _ = toy_streams(2, 6, seed=3)
    f = HBNIFilter(DrawsPosterior(draws, torch.tensor(prior, dtype=DT)))
    probs = f.run(obs)
    for b in range(2):
        ref = _brute_force_hbni(obs[b].numpy(), draws.numpy(), prior)
        np.testing.assert_allclose(probs[b].numpy(), ref, rtol=1e-9)


def test_hbni_plugin_uses_the_posterior_median_and_matches_torch_dirichlet():
    draws = torch.tensor([[1.0, 2.0, 3.0], [2.0, 9.0, 4.0], [30.0, 5.0, 50.0]], dtype=DT)
    f = HBNIFilter(DrawsPosterior(draws), "plugin")
    median = torch.tensor([2.0, 5.0, 4.0], dtype=DT)
    torch.testing.assert_close(f.theta, median.unsqueeze(0))
    obs, _ = toy_streams(1, 5, seed=4)
    loglik = torch.stack(
        [torch.distributions.Dirichlet(1 + median[m] * torch.eye(3, dtype=DT)[m]).log_prob(obs[0]) for m in range(3)],
        -1,
    )
    expected = torch.softmax(loglik.cumsum(0) + math.log(1 / 3), -1)
    torch.testing.assert_close(f.run(obs)[0], expected, rtol=1e-12, atol=1e-14)


def test_hbni_with_identical_draws_equals_the_plugin_and_reads_the_class_prior():
    prior = torch.tensor([0.6, 0.3, 0.1], dtype=DT)
    same = DrawsPosterior(THETA.expand(40, 3), prior)
    obs, _ = toy_streams(5, 8)
    marginal, plugin = HBNIFilter(same).run(obs), HBNIFilter(same, "plugin").run(obs)
    torch.testing.assert_close(marginal, plugin, rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(HBNIFilter(same).class_prior, prior)
    uniform = HBNIFilter(same, class_prior=[1 / 3, 1 / 3, 1 / 3])
    assert not torch.allclose(uniform.run(obs), marginal)


def test_hbni_thins_draws_evenly():
    draws = torch.arange(1, 301, dtype=DT).unsqueeze(-1).expand(300, 3)
    f = HBNIFilter(DrawsPosterior(draws), num_draws=4)
    assert f.theta[:, 0].tolist() == [1.0, 101.0, 200.0, 300.0]
    assert HBNIFilter(DrawsPosterior(draws), num_draws=1000).theta.shape == (300, 3)


def test_hbni_accepts_a_real_posterior():
    theta = scattered_draws(60).reshape(3, 20, 3)
    post = HBNIPosterior(
        {"theta": theta, "kappa": torch.ones(3, 20, dtype=DT), "gamma": torch.ones(3, 20, dtype=DT)},
        torch.full((3,), 1 / 3, dtype=DT),
    )
    obs, _ = toy_streams(3, 4)
    torch.testing.assert_close(HBNIFilter(post).run(obs), HBNIFilter(DrawsPosterior(theta.reshape(60, 3))).run(obs))


def test_hbni_with_the_true_theta_beats_ssbf():
    """At N = 3 on the toy, the oracle HBNI filter's error is below SSBF's by more than 5 standard
    errors of the difference of the two binomial proportions (4000 streams)."""
    obs, truth = toy_streams(4000, 3, seed=11)
    oracle = DrawsPosterior(THETA.unsqueeze(0))
    err_hbni = (decide(HBNIFilter(oracle).run(obs)[:, -1]) != truth).double().mean()
    err_ssbf = (decide(StaticStateBayesFilter(3).run(obs)[:, -1]) != truth).double().mean()
    se = math.sqrt((err_hbni * (1 - err_hbni) + err_ssbf * (1 - err_ssbf)) / 4000)
    assert err_hbni + 5 * se < err_ssbf


# -- streaming equals batched -------------------------------------------------------------------


@pytest.mark.parametrize("f", all_filters(), ids=repr)
def test_streaming_and_batched_agree_exactly(f):
    obs, _ = toy_streams(12, 15, seed=5)
    obs[0, 2] = torch.tensor([0.0, 1.0, 0.0], dtype=DT)  # exact zeros are floored in both paths
    batched = f.run(obs)
    assert batched.shape == (12, 15, 3)
    assert torch.allclose(batched.sum(-1), torch.ones(12, 15, dtype=DT))
    for b in range(12):
        f.reset()
        for n in range(15):
            assert torch.equal(f.update(obs[b, n]), batched[b, n])
        assert f.frames_seen == 15
    f.reset()
    assert f.frames_seen == 0


def test_at_one_frame_voting_max_of_mean_and_ssbf_decide_alike():
    obs, _ = toy_streams(3000, 1, seed=6)
    ties = torch.tensor([[[0.4, 0.4, 0.2]], [[0.2, 0.4, 0.4]], [[1 / 3, 1 / 3, 1 / 3]], [[0.5, 0.0, 0.5]]], dtype=DT)
    obs = torch.cat([obs, ties])
    decisions = [decide(f.run(obs)[:, 0]) for f in (VotingFilter(3), MaxOfMeanFilter(3), StaticStateBayesFilter(3))]
    assert torch.equal(decisions[0], decisions[1]) and torch.equal(decisions[1], decisions[2])
    assert decisions[0][-4:].tolist() == [0, 1, 0, 0]


def test_exact_zeros_are_floored():
    f = StaticStateBayesFilter(3)
    probs = f.update([0.0, 1.0, 0.0])
    assert torch.isfinite(probs).all() and probs.min() > 0
    torch.testing.assert_close(probs[0], torch.tensor(OUTPUT_FLOOR, dtype=DT), rtol=1e-5, atol=0)


# -- bad input ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "row, message",
    [
        ([0.5, -0.1, 0.6], "negative"),
        ([0.5, float("nan"), 0.5], "NaN"),
        ([0.5, 0.2, 0.2], "sums to"),
        ([0.5, 0.5], "width M = 3"),
    ],
)
def test_bad_rows_are_rejected_with_the_row_named(row, message):
    f = MaxOfMeanFilter(3)
    with pytest.raises(ValueError, match=message):
        f.update(row)
    obs = torch.full((2, 4, 3), 1 / 3, dtype=DT)
    if len(row) == 3:
        obs[1, 2] = torch.tensor(row, dtype=DT)
        with pytest.raises(ValueError, match=r"row \(1, 2\)"):
            f.run(obs)


def test_shape_and_argument_errors():
    with pytest.raises(ValueError, match="num_classes"):
        VotingFilter(1)
    with pytest.raises(TypeError, match="num_classes: expected an int, got True"):
        StaticStateBayesFilter(True)
    with pytest.raises(ValueError, match="one output"):
        StaticStateBayesFilter(3).update(torch.full((2, 3), 1 / 3))
    with pytest.raises(ValueError, match=r"\(B, N, M\)"):
        StaticStateBayesFilter(3).run(torch.full((2, 2, 2, 3), 1 / 3))
    with pytest.raises(ValueError, match="at least 3"):
        StaticStateBayesFilter(3).run(torch.full((2, 3), 1 / 3))
    with pytest.raises(TypeError, match="obs"):
        StaticStateBayesFilter(3).run("abc")
    with pytest.raises(ValueError, match="class_prior"):
        StaticStateBayesFilter(3, class_prior=[0.5, 0.5])
    post = DrawsPosterior(scattered_draws(5))
    with pytest.raises(ValueError, match="mode"):
        HBNIFilter(post, mode="mean")
    with pytest.raises(ValueError, match="num_draws"):
        HBNIFilter(post, num_draws=0)
    with pytest.raises(TypeError, match="posterior"):
        HBNIFilter(THETA)
    with pytest.raises(ValueError, match="> 0"):
        HBNIFilter(DrawsPosterior(-scattered_draws(5)))
    with pytest.raises(ValueError, match="class_prior"):
        HBNIFilter(post, class_prior=[0.2, 0.8])
    assert not isinstance(THETA, StreamingFilter)


def test_make_filter_builds_every_named_filter():
    post = DrawsPosterior(THETA[None].expand(4, -1).clone())
    obs = sample_outputs(THETA, torch.tensor([0, 1, 2]), torch.Generator().manual_seed(0)).reshape(1, 3, -1)
    identity = FrameCalibration(torch.eye(len(THETA)), torch.zeros(len(THETA)))
    built = {
        name: make_filter(name, post, **({"calibration": identity} if name == "calibrated" else {})) for name in FILTERS
    }
    want = {
        "hbni": HBNIFilter(post),
        "calibrated": StaticStateBayesFilter(len(THETA)),
        "ssbf": StaticStateBayesFilter(len(THETA)),
        "max_of_mean": MaxOfMeanFilter(len(THETA)),
        "voting": VotingFilter(len(THETA)),
    }
    for name in FILTERS:
        assert type(built[name]) is type(want[name])
        exact = {} if name == "calibrated" else {"rtol": 0, "atol": 0}  # the identity map renormalises in log space
        torch.testing.assert_close(built[name].run(obs), want[name].run(obs), **exact)
    assert make_filter("hbni", post, mode="plugin", temper=0.5).mode == "plugin"
    assert make_filter("ssbf", num_classes=4).num_classes == 4


@pytest.mark.parametrize(
    "args, kwargs, error, message",
    [
        (("kalman",), {}, ValueError, "name: expected one of"),
        (("hbni",), {}, ValueError, "posterior: the 'hbni' filter needs a fitted posterior"),
        (("voting",), {}, ValueError, "num_classes: the 'voting' filter needs num_classes or a posterior"),
        (("voting",), {"num_classes": 3, "temper": 0.5}, TypeError, "the 'voting' filter takes no options, got"),
    ],
)
def test_make_filter_errors(args, kwargs, error, message):
    with pytest.raises(error, match=message):
        make_filter(*args, **kwargs)
