"""The HBNI filter under the confusion-aware and sequence-aware models: brute force, streaming ==
batched, plug-in mode, and bad posteriors; their posteriors' storage and predictive."""

import math

import pytest
import torch

from hbni_pyro import HBNIFilter, HBNIPosterior, sample_dirichlet, sample_sequences
from hbni_pyro.distributions import concentrations
from hbni_pyro.models.sequence.program import TwoLevelSequence

DT = torch.float64
M = 3


def confusion_posterior(num_draws=40, seed=0):
    g = torch.Generator().manual_seed(seed)
    theta = torch.tensor([2.0, 6.0, 12.0], dtype=DT) * torch.exp(
        0.3 * torch.randn(2, num_draws // 2, M, generator=g, dtype=DT)
    )
    beta = torch.exp(0.5 * torch.randn(2, num_draws // 2, M, M, generator=g, dtype=DT)) * 0.7
    beta = beta.masked_fill(torch.eye(M, dtype=torch.bool), 1.0)
    ones = torch.ones(2, num_draws // 2, dtype=DT)
    samples = {"theta": theta, "beta": beta, "kappa": ones, "gamma": ones, "beta_loc": ones * 0, "beta_scale": ones}
    return HBNIPosterior(samples, torch.full((M,), 1 / M, dtype=DT), model="confusion")


def sequence_posterior(num_draws=30, seed=0):
    g = torch.Generator().manual_seed(seed)
    S = num_draws // 2
    loc = torch.tensor([[1.2, 0.1], [-0.7, 1.0], [-0.6, -1.1]], dtype=DT) + 0.1 * torch.randn(
        2, S, M, 2, generator=g, dtype=DT
    )
    a = 0.4 * torch.randn(2, S, M, 2, 2, generator=g, dtype=DT)
    between = a @ a.transpose(-1, -2) + 0.1 * torch.eye(2, dtype=DT)
    b = 0.3 * torch.randn(2, S, 2, 2, generator=g, dtype=DT)
    within = b @ b.transpose(-1, -2) + 0.2 * torch.eye(2, dtype=DT)
    samples = {
        "loc": loc,
        "between": between,
        "between_mean": within.clone(),
        "between_pooling": torch.ones(2, S, dtype=DT),
        "within": within,
    }
    return HBNIPosterior(samples, torch.tensor([0.5, 0.3, 0.2], dtype=DT), model="sequence")


def confusion_streams(num, length, seed=1):
    g = torch.Generator().manual_seed(seed)
    alpha = torch.tensor([[5.0, 2.0, 0.4], [0.6, 9.0, 0.5], [0.3, 0.3, 4.0]], dtype=DT)
    classes = torch.randint(0, M, (num,), generator=g)
    return sample_dirichlet(alpha[classes].unsqueeze(1).expand(num, length, M), g), classes


def sequence_streams(num, length, seed=1):
    g = torch.Generator().manual_seed(seed)
    post = sequence_posterior(seed=5)
    classes = torch.randint(0, M, (num,), generator=g)
    d = post.draws()
    return sample_sequences(d["loc"][0], d["between"][0], d["within"][0], classes, length, g), classes


def log_mean_exp(x, dim=0):
    return torch.logsumexp(x, dim) - math.log(x.shape[dim])


def test_confusion_filter_matches_a_brute_force_loop_over_draws_and_frames():
    post = confusion_posterior()
    obs, _ = confusion_streams(3, 6)
    probs = HBNIFilter(post).run(obs)
    draws = post.draws()
    alpha = concentrations(draws["theta"], draws["beta"])  # (S, M, M)
    for b in range(3):
        loglik = torch.zeros(alpha.shape[0], M, dtype=DT)
        for n in range(6):
            loglik += torch.stack(
                [torch.distributions.Dirichlet(alpha[:, c]).log_prob(obs[b, n]) for c in range(M)], -1
            )
            expected = torch.softmax(post.class_prior.log() + log_mean_exp(loglik), -1)
            torch.testing.assert_close(probs[b, n], expected, rtol=0, atol=1e-10)


def test_sequence_filter_integrates_the_look_out_exactly():
    """Against the joint Gaussian density of each prefix (TwoLevelSequence), draw by draw."""
    post = sequence_posterior()
    obs, _ = sequence_streams(3, 5)
    probs = HBNIFilter(post).run(obs)
    d = post.draws()
    for b in range(3):
        for n in range(1, 6):
            mask = torch.zeros(5, dtype=torch.bool)
            mask[:n] = True
            lik = torch.stack(
                [
                    TwoLevelSequence(
                        d["loc"][:, c], d["between"][:, c], d["within"], mask.expand(d["loc"].shape[0], 5)
                    ).log_prob(obs[b])
                    for c in range(M)
                ],
                -1,
            )  # (S, M)
            expected = torch.softmax(post.class_prior.log() + log_mean_exp(lik), -1)
            torch.testing.assert_close(probs[b, n - 1], expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "make, streams", [(confusion_posterior, confusion_streams), (sequence_posterior, sequence_streams)]
)
@pytest.mark.parametrize("mode", ["marginal", "plugin"])
def test_streaming_equals_batched(make, streams, mode):
    post = make()
    obs, _ = streams(4, 7)
    f = HBNIFilter(post, mode, num_draws=17, temper=0.7)
    batched = f.run(obs)
    for b in range(4):
        f.reset()
        stream = torch.stack([f.update(o) for o in obs[b]])
        torch.testing.assert_close(stream, batched[b], rtol=0, atol=1e-12)
        assert f.frames_seen == 7


def test_plugin_mode_uses_one_point_estimate():
    post = confusion_posterior()
    f = HBNIFilter(post, "plugin")
    torch.testing.assert_close(f.draws["beta"][0], post.draws()["beta"].median(0).values)
    s = HBNIFilter(sequence_posterior(), "plugin")
    torch.testing.assert_close(s.draws["between"][0], sequence_posterior().draws()["between"].mean(0))
    assert "model='sequence'" in repr(s) and "draws=1" in repr(s)


def test_sequence_filter_saturates_where_the_paper_filter_does_not():
    """Repeating one frame adds no new evidence about the look once it is known: the posterior
    converges instead of running to certainty."""
    post = sequence_posterior()
    obs, _ = sequence_streams(1, 1)
    repeated = obs.expand(1, 400, M)
    probs = HBNIFilter(post).run(repeated)[0]
    gap = (probs[-1] - probs[-2]).abs().max()
    assert gap < 1e-3 and probs[-1].max() < 1 - 1e-6


def test_filter_rejects_bad_variant_posteriors():
    bad = sequence_posterior()
    bad.samples["within"][0, 0] = -torch.eye(2, dtype=DT)
    with pytest.raises(ValueError, match="within draw must be a positive-definite"):
        HBNIFilter(bad)
    bad = confusion_posterior()
    bad.samples["beta"][0, 0, 0, 1] = -1.0
    with pytest.raises(ValueError, match="must be finite and > 0"):
        HBNIFilter(bad)


# -- posteriors of the variants: storage, summary, predictive ------------------------------------


@pytest.mark.parametrize("make", [confusion_posterior, sequence_posterior])
def test_variant_posterior_round_trip_and_summary(make, tmp_path):
    post = make()
    back = HBNIPosterior.load(post.save(tmp_path / "p.safetensors"))
    assert back.model == post.model and back.num_classes == M
    for k in post.samples:
        assert torch.equal(back.samples[k], post.samples[k])
    summary = post.summary()
    if post.model == "confusion":
        assert "beta[0, 1]" in summary and "beta[0, 0]" not in summary and "beta_scale" in summary
    else:
        assert {"loc[2, 1]", "between[0, 0, 1]", "within[0, 1]", "between_pooling"} <= set(summary)
        assert "within[1, 0]" not in summary
        with pytest.raises(ValueError, match="has no theta"):
            post.theta_draws()


@pytest.mark.parametrize("make", [confusion_posterior, sequence_posterior])
def test_variant_posterior_predictive_streams(make):
    post = make()
    a = post.sample_streams(1, 50, 6, seed=3)
    assert a.shape == (50, 6, M) and torch.equal(a, post.sample_streams(1, 50, 6, seed=3))
    torch.testing.assert_close(a.sum(-1), torch.ones(50, 6, dtype=DT))
    assert post.sample_outputs(2, 5).shape == (5, M)
    with pytest.raises(ValueError, match="num_frames"):
        post.sample_streams(0, 2, 0)


def test_posterior_validates_the_sites_of_its_model(tmp_path):
    good = sequence_posterior()
    with pytest.raises(ValueError, match=r"missing sites \['within'\]"):
        HBNIPosterior({k: v for k, v in good.samples.items() if k != "within"}, good.class_prior, model="sequence")
    with pytest.raises(ValueError, match="model: expected one of"):
        HBNIPosterior(good.samples, good.class_prior, model="mixture")
    wrong = dict(good.samples, within=good.samples["within"][..., :1])
    with pytest.raises(ValueError, match=r"samples\['within'\]"):
        HBNIPosterior(wrong, good.class_prior, model="sequence")
