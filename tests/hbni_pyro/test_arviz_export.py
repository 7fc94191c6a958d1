"""The ArviZ export: the three noise models fitted to one data set (sequences, half of them labelled) compared by
az.loo and az.compare on the same units; each pointwise log likelihood checked against an independent density
(torch's Dirichlet, the sequence model's Pyro distribution); the predictive draws az.plot_ppc plots; sample
statistics against the fit's own record; names, dims and a save/load round trip."""

import math
import warnings

import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_sequences
from hbni_pyro.models.paper.program import log_joint
from hbni_pyro.models.sequence.program import TwoLevelSequence, look_prior_mean

az = pytest.importorskip("arviz")

NAMES = ["ambulance", "food_crate", "police_car"]
K, T, M = 9, 6, 3


@pytest.fixture(scope="module")
def data():
    g = torch.Generator().manual_seed(0)
    classes = torch.arange(M).repeat_interleave(K // M)
    between = 0.4 * torch.eye(M - 1, dtype=torch.float64).expand(M, M - 1, M - 1)
    within = 0.3 * torch.eye(M - 1, dtype=torch.float64)
    seqs = sample_sequences(look_prior_mean(M, 2.0), between, within, classes, T, g)
    ids = torch.arange(K).repeat_interleave(T)
    labels = torch.where(ids % 2 == 0, classes.repeat_interleave(T), -1)  # every other sequence unlabelled
    return seqs.reshape(-1, M), labels, ids


@pytest.fixture(scope="module")
def fitted(data):
    obs, labels, ids = data
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            model: hbni_pyro.fit(
                obs,
                labels,
                model=model,
                sequence_ids=ids,
                class_names=NAMES,
                num_chains=2,
                num_samples=100,
                warmup_steps=100,
                seed=1,
                progress=False,
            )
            for model in ("paper", "confusion", "sequence")
        }


@pytest.fixture(scope="module")
def exported(fitted):
    return {model: post.to_arviz(predictive_draws=20, seed=3) for model, post in fitted.items()}


def test_loo_and_compare_rank_the_three_models_on_the_same_sequences(exported):
    for model, idata in exported.items():
        assert set(idata.groups()) == {
            "posterior",
            "sample_stats",
            "observed_data",
            "log_likelihood",
            "posterior_predictive",
        }, model
        assert idata.log_likelihood["outputs"].dims == ("chain", "draw", "sequence")
        assert idata.log_likelihood["outputs"].shape == (2, 100, K)
        loo = az.loo(idata)
        assert math.isfinite(loo.elpd_loo) and loo.n_data_points == K
    table = az.compare(exported)
    assert sorted(table.index) == ["confusion", "paper", "sequence"] and sorted(table["rank"]) == [0, 1, 2]
    assert table["elpd_loo"].is_monotonic_decreasing


def test_frame_models_pointwise_log_likelihood_is_torchs_dirichlet_summed_per_sequence(fitted, exported, data):
    obs, labels, ids = data
    for model in ("paper", "confusion"):
        post, log_lik = fitted[model], torch.as_tensor(exported[model].log_likelihood["outputs"].values)
        for chain, draw in ((0, 0), (1, 57)):
            s = {k: v[chain, draw] for k, v in post.samples.items()}
            beta = s["beta"] if model == "confusion" else torch.ones(M, M, dtype=torch.float64)
            assert torch.equal(beta.diagonal(), torch.ones(M, dtype=torch.float64))
            alpha = torch.diag(s["theta"]) + beta  # row c: theta_c e_c + beta_c
            per_class = torch.stack([torch.distributions.Dirichlet(alpha[c]).log_prob(obs) for c in range(M)], -1)
            frame = torch.where(
                labels >= 0,
                per_class.gather(-1, labels.clamp_min(0)[:, None])[:, 0],
                torch.logsumexp(per_class + post.class_prior.log(), -1),
            )
            expected = torch.zeros(K, dtype=torch.float64).index_add_(0, ids, frame)
            assert torch.allclose(log_lik[chain, draw], expected, rtol=1e-9, atol=1e-9), model
    # lp is the log joint of the draw, the labelled frames' class prior left out (they are conditioned on)
    post, lp = fitted["paper"], torch.as_tensor(exported["paper"].sample_stats["lp"].values)
    s = {k: v[1, 57] for k, v in post.samples.items()}
    joint = log_joint(obs, s["theta"], s["kappa"], s["gamma"], labels, post.class_prior, post.hyperprior)
    known = post.class_prior.log()[labels[labels >= 0]].sum()
    assert float(lp[1, 57]) == pytest.approx(float(joint - known), rel=1e-10)


def test_the_sequence_models_pointwise_log_likelihood_is_its_pyro_distributions(fitted, exported, data):
    obs, labels, ids = data
    post, log_lik = fitted["sequence"], torch.as_tensor(exported["sequence"].log_likelihood["outputs"].values)
    s = {k: v[1, 31] for k, v in post.samples.items()}
    mask = torch.ones(T, dtype=torch.bool)
    for k in range(K):
        frames = obs[ids == k]
        per_class = torch.stack(
            [TwoLevelSequence(s["loc"][c], s["between"][c], s["within"], mask).log_prob(frames) for c in range(M)]
        )
        label = int(labels[ids == k][0])
        expected = per_class[label] if label >= 0 else torch.logsumexp(per_class + post.class_prior.log(), 0)
        assert float(log_lik[1, 31, k]) == pytest.approx(float(expected), rel=1e-9)


def test_names_dims_predictive_draws_and_sample_stats(fitted, exported, data):
    obs, labels, _ = data
    idata = exported["confusion"]
    assert list(idata.posterior["theta"].coords["class"].values) == NAMES
    assert idata.posterior["beta"].dims == ("chain", "draw", "class", "class_to")
    assert exported["sequence"].posterior["between"].dims == ("chain", "draw", "class", "coord", "coord_to")
    assert torch.allclose(torch.as_tensor(idata.observed_data["outputs"].values), obs, atol=1e-6)  # floored rows
    assert torch.equal(torch.as_tensor(idata.observed_data["labels"].values), labels)
    for model, data_ in exported.items():
        pp = torch.as_tensor(data_.posterior_predictive["outputs"].values)
        assert pp.shape == (2, 10, K * T, M) and torch.allclose(
            pp.sum(-1), torch.ones((), dtype=pp.dtype), atol=1e-9
        ), model
        assert (pp > 0).all()
    # the replicated outputs of a labelled frame put most weight on its class under the (well separated) model
    pp = torch.as_tensor(exported["paper"].posterior_predictive["outputs"].values)
    known = labels >= 0
    hits = (pp.argmax(-1)[..., known] == labels[known]).double().mean()
    assert hits > 0.6
    # acceptance: a draw equal to the one before it was a rejected move; the theta walk's share matches the fit's
    post = fitted["paper"]
    theta = post.samples["theta"]
    moved = (theta[:, 1:] != theta[:, :-1]).double().mean()
    assert float(moved) == pytest.approx(post.info["acceptance_rate"]["theta"], abs=3 / theta[0].numel() ** 0.5)
    rate = torch.as_tensor(exported["paper"].sample_stats["acceptance_rate"].values)
    assert rate[:, 0].isnan().all() and ((rate[:, 1:] >= 0) & (rate[:, 1:] <= 1)).all()
    import matplotlib.pyplot as plt

    az.plot_ppc(exported["sequence"], var_names=["outputs"], num_pp_samples=5)
    plt.close("all")


def test_the_fitted_data_survive_save_and_load(fitted, exported, tmp_path):
    post = fitted["sequence"]
    again = hbni_pyro.HBNIPosterior.load(post.save(tmp_path / "p.safetensors"))
    for name, value in post.fitted_data().items():
        assert torch.equal(getattr(again, name), value), name
    loaded = again.to_arviz(predictive_draws=0)
    assert "posterior_predictive" not in loaded.groups()
    assert (loaded.log_likelihood["outputs"].values == exported["sequence"].log_likelihood["outputs"].values).all()
    bare = hbni_pyro.HBNIPosterior(post.samples, post.class_prior, model="sequence")  # built by hand: no data
    assert set(bare.to_arviz().groups()) == {"posterior"}
