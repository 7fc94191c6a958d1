"""The AR(1) correlation of frames about their look: closed form against brute force, the draws' moments,
the estimator's recovery within its sampling error, and the posterior carrying it (fit, save/load, streams)."""

import math
import pickle

import pytest
import torch

import hbni_pyro
import hbni_pyro.models.sequence.correlation as fc
from hbni_pyro import HBNIPosterior, sample_outputs, sample_sequences
from hbni_pyro.distributions import helmert_basis
from hbni_pyro.models import estimate_frame_correlation
from hbni_pyro.models.sequence.correlation import LIMIT, ar1_normals, lag_one_ratio

D = torch.float64


def centred_covariance(rho: float, n: int) -> torch.Tensor:
    """``C R C``: the covariance of ``n`` unit-variance AR(1) frames centred on their own mean, explicitly."""
    i = torch.arange(n, dtype=D)
    centre = torch.eye(n, dtype=D) - 1.0 / n
    return centre @ rho ** (i[:, None] - i[None, :]).abs() @ centre


@pytest.mark.parametrize("rho", [-0.6, 0.0, 0.35, 0.8, 0.97])
def test_lag_one_ratio_matches_the_explicit_covariance(rho):
    lengths = [3, 30, 30, 7, 2]
    covs = [centred_covariance(rho, n) for n in lengths]
    for n, m in zip(lengths, covs):
        expected = float(torch.diagonal(m, 1).sum() / torch.trace(m))
        assert lag_one_ratio(rho, torch.tensor([n])) == pytest.approx(expected, abs=1e-12)
    pooled = sum(float(torch.diagonal(m, 1).sum()) for m in covs) / sum(float(torch.trace(m)) for m in covs)
    assert lag_one_ratio(rho, torch.tensor(lengths)) == pytest.approx(pooled, abs=1e-12)
    assert lag_one_ratio(0.0, torch.tensor([5])) == pytest.approx(-1 / 5)


def test_ar1_normals_have_unit_variance_and_geometric_correlation():
    """Each step's variance is 1 and lag-k correlation rho^k, within 5 standard errors of 20 000 series."""
    rho, n = 0.7, 20_000
    z = ar1_normals((n, 12, 1), rho, torch.Generator().manual_seed(0))[..., 0]
    var = z.var(0)
    assert (var - 1).abs().max() < 5 * math.sqrt(2 / n)
    for lag in (1, 2, 5):
        corr = (z[:, lag:] * z[:, :-lag]).mean(0)  # mean 0, variance 1
        se = math.sqrt((1 + rho ** (2 * lag)) / n)
        assert (corr - rho**lag).abs().max() < 5 * se, (lag, corr)
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    assert torch.equal(ar1_normals((4, 6, 2), 0.0, g1), torch.randn(4, 6, 2, generator=g2, dtype=D))


def _streams(rho: float, num_seq: int, frames: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``num_seq`` sequences of AR(1) frames about random looks, an anisotropic scatter, as (N, 4) outputs."""
    g = torch.Generator().manual_seed(seed)
    within = torch.tensor([[1.0, 0.4, 0.0], [0.4, 2.0, 0.0], [0.0, 0.0, 0.5]], dtype=D)
    look = 2.0 * torch.randn(num_seq, 1, 3, generator=g, dtype=D)
    y = look + (torch.linalg.cholesky(within) @ ar1_normals((num_seq, frames, 3), rho, g).unsqueeze(-1)).squeeze(-1)
    out = torch.softmax(y @ helmert_basis(4, D, "cpu"), -1)
    return out.reshape(-1, 4), torch.arange(num_seq).repeat_interleave(frames)


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.8])
def test_estimate_recovers_the_correlation_within_its_sampling_error(rho):
    """The spread of the estimate over 12 independent data sets (300 sequences of 20 frames) gives its standard
    error; every estimate lies within 5 of them of the truth, and their mean within 5 of the mean's."""
    estimates = torch.tensor([estimate_frame_correlation(*_streams(rho, 300, 20, seed)) for seed in range(12)])
    se = float(estimates.std())
    assert 0 < se < 0.05
    assert (estimates - rho).abs().max() < 5 * se
    assert abs(float(estimates.mean()) - rho) < 5 * se / math.sqrt(12)


def test_estimate_uses_time_order_within_interleaved_sequences_and_skips_short_ones():
    obs, ids = _streams(0.6, 200, 15, 1)
    round_robin = torch.arange(obs.shape[0]).view(200, 15).T.reshape(-1)  # every sequence's first frame, ...
    assert estimate_frame_correlation(obs, ids) == pytest.approx(
        estimate_frame_correlation(obs[round_robin], ids[round_robin]), abs=1e-12
    )
    shuffled = torch.randperm(obs.shape[0], generator=torch.Generator().manual_seed(2))
    assert abs(estimate_frame_correlation(obs[shuffled], ids[shuffled])) < 0.1  # time order lost: about 0
    whole = estimate_frame_correlation(obs, ids)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fc, "_ROWS", 7)  # chunks that split sequences: the same sums
        assert estimate_frame_correlation(obs, ids) == pytest.approx(whole, abs=1e-12)
    short = torch.cat([obs, obs[:2]]), torch.cat([ids, torch.tensor([500, 500])])
    assert estimate_frame_correlation(*short) == pytest.approx(estimate_frame_correlation(obs, ids), abs=1e-12)
    assert estimate_frame_correlation(obs[:2], torch.zeros(2, dtype=torch.long)) == 0.0
    same = obs[:1].expand(5, -1)  # no scatter at all
    assert estimate_frame_correlation(same, torch.zeros(5, dtype=torch.long)) == 0.0
    smooth = torch.softmax(torch.linspace(0, 1, 40, dtype=D).view(-1, 1) * torch.tensor([[1.0, -1.0, 0.0]]), -1)
    assert estimate_frame_correlation(smooth, torch.zeros(40, dtype=torch.long)) == LIMIT


def test_evidence_kept_per_count_gives_the_same_bits_as_computed_afresh():
    """Look variances are kept per frame count: a warm evidence, a fresh one, rows of one count and rows of mixed
    counts (computed without the kept variances) give identical values."""
    from hbni_pyro.models import SequenceEvidence

    g = torch.Generator().manual_seed(5)
    obs = torch.softmax(2 * torch.randn(12, 6, 3, generator=g, dtype=D), -1)
    warm = SequenceEvidence(_two_draws(), correlation=0.4)
    feats = warm.features(obs)
    for n in range(1, 7):
        warm.log_evidence(feats[:, :n].sum(1), torch.full((12,), float(n), dtype=D))
    counts = torch.tensor([2.0] * 6 + [5.0] * 6, dtype=D)
    stats = torch.cat([feats[:6, :2].sum(1), feats[6:, :5].sum(1)])
    mixed = SequenceEvidence(_two_draws(), correlation=0.4).log_evidence(stats, counts)
    for rows, n in ((slice(0, 6), 2.0), (slice(6, 12), 5.0)):
        alone = torch.full((6,), n, dtype=D)
        fresh = SequenceEvidence(_two_draws(), correlation=0.4).log_evidence(stats[rows], alone)
        assert torch.equal(warm.log_evidence(stats[rows], alone), fresh)
        assert torch.equal(mixed[rows], fresh)
    copy = pickle.loads(pickle.dumps(warm))
    assert copy._variances == {} and torch.equal(copy.log_evidence(stats, counts), mixed)


def test_correlated_sequences_keep_the_scatter_and_correlate_neighbours():
    """Frames about their look: covariance ``within`` at each step and ``rho within`` between neighbours
    (each entry within 5 standard errors of 8000 sequences)."""
    rho, n = 0.75, 8000
    loc = torch.zeros(3, 2, dtype=D)
    between = torch.eye(2, dtype=D).expand(3, 2, 2) * 1e-12
    within = torch.tensor([[1.0, 0.3], [0.3, 0.5]], dtype=D)
    out = sample_sequences(
        loc, between, within, torch.zeros(n, dtype=torch.long), 6, torch.Generator().manual_seed(4), rho
    )
    y = out.log() @ helmert_basis(3, D, "cpu").T
    cov0 = torch.einsum("ni,nj->ij", y[:, 3], y[:, 3]) / n
    cov1 = torch.einsum("ni,nj->ij", y[:, 3], y[:, 4]) / n
    scale = within.diagonal().sqrt()
    se = (scale[:, None] * scale[None, :]) * math.sqrt(2 / n)
    assert ((cov0 - within).abs() < 5 * se).all(), cov0
    assert ((cov1 - rho * within).abs() < 5 * se).all(), cov1


def _sequence_posterior(rho: float = 0.0) -> HBNIPosterior:
    M, d = 3, 2
    samples = {
        "loc": 2.0 * torch.eye(M, d, dtype=D).expand(1, 20, M, d).clone(),
        "between": 0.2 * torch.eye(d, dtype=D).expand(1, 20, M, d, d).clone(),
        "between_mean": 0.2 * torch.eye(d, dtype=D).expand(1, 20, d, d).clone(),
        "between_pooling": torch.full((1, 20), 5.0, dtype=D),
        "within": torch.eye(d, dtype=D).expand(1, 20, d, d).clone(),
    }
    return hbni_pyro.posterior.posterior_from_samples(
        samples, torch.full((M,), 1 / M), hbni_pyro.HyperPrior(), "sequence", frame_correlation=rho
    )


def test_posterior_streams_carry_the_correlation_and_round_trip(tmp_path):
    post = _sequence_posterior(0.8)
    back = HBNIPosterior.load(post.save(tmp_path / "post.safetensors"))
    assert back.frame_correlation == 0.8 and "frame_correlation=0.800" in repr(back)
    assert back.to("cpu").frame_correlation == 0.8
    a, b = post.sample_streams(1, 3000, 8, seed=5), back.sample_streams(1, 3000, 8, seed=5)
    assert torch.equal(a, b)
    y = a.log() @ helmert_basis(3, D, "cpu").T
    e = y - y.mean(1, keepdim=True)
    observed = float((e[:, 1:] * e[:, :-1]).sum() / (e * e).sum())
    assert observed == pytest.approx(lag_one_ratio(0.8, torch.tensor([8])), abs=0.02)  # s.e. about 0.005
    iid = _sequence_posterior(0.0).sample_streams(1, 3000, 8, seed=5)
    assert not torch.equal(iid, a)


def test_posterior_refuses_a_bad_correlation():
    with pytest.raises(ValueError, match=r"frame_correlation: .*\(-1, 1\)|frame_correlation"):
        _sequence_posterior(1.0)
    with pytest.raises(TypeError, match="frame_correlation"):
        _sequence_posterior("0.5")
    theta = torch.ones(1, 4, 3, dtype=D)
    ones = torch.ones(1, 4, dtype=D)
    with pytest.raises(ValueError, match="'paper' model draws frames i.i.d."):
        hbni_pyro.posterior.posterior_from_samples(
            {"theta": theta, "kappa": ones, "gamma": ones},
            torch.full((3,), 1 / 3),
            hbni_pyro.HyperPrior(),
            frame_correlation=0.3,
        )


def test_a_sequence_fit_estimates_the_correlation_and_a_frame_level_fit_does_not():
    obs, ids = _streams(0.7, 60, 10, 7)
    obs = obs[:, :3] / obs[:, :3].sum(-1, keepdim=True)
    labels = (ids % 3).long()
    post = hbni_pyro.fit(
        obs, labels, model="sequence", sequence_ids=ids, num_chains=2, num_samples=20, warmup_steps=20, progress=False
    )
    assert post.frame_correlation == pytest.approx(estimate_frame_correlation(obs, ids), abs=1e-12)
    assert post.frame_correlation > 0.3
    many = hbni_pyro.fit_many(
        torch.stack([obs, obs]),
        torch.stack([labels, labels]),
        model="sequence",
        sequence_ids=ids,
        num_chains=2,
        num_samples=10,
        warmup_steps=10,
        progress=False,
    )
    assert [p.frame_correlation for p in many] == [post.frame_correlation] * 2
    flat = hbni_pyro.fit(
        sample_outputs(torch.tensor([2.0, 3.0]), torch.arange(2).repeat(5), torch.Generator().manual_seed(0)),
        num_chains=2,
        num_samples=10,
        warmup_steps=10,
        progress=False,
    )
    assert flat.frame_correlation == 0.0


def _two_draws() -> dict[str, torch.Tensor]:
    """Two draws of a three-class sequence model that differ in every site."""
    g = torch.Generator().manual_seed(11)
    a = torch.randn(2, 2, 2, generator=g, dtype=D)
    b = torch.randn(2, 3, 2, 2, generator=g, dtype=D)
    return {
        "loc": torch.randn(2, 3, 2, generator=g, dtype=D),
        "between": b @ b.transpose(-1, -2) + 0.3 * torch.eye(2, dtype=D),
        "within": a @ a.transpose(-1, -2) + 0.5 * torch.eye(2, dtype=D),
    }


@pytest.mark.parametrize("rho", [0.0, 0.6, -0.3])
def test_lagged_evidence_is_the_joint_gaussian_of_ar1_frames(rho):
    """``log mean_s N(y_1:n; 1 loc_c, 1 1^T between_c + R(rho) within)`` for every class, by brute force."""
    from hbni_pyro.models import SequenceEvidence

    draws = _two_draws()
    evidence = SequenceEvidence(draws, correlation=rho)
    g = torch.Generator().manual_seed(12)
    for n in (1, 2, 5):
        obs = torch.softmax(torch.randn(n, 3, generator=g, dtype=D), -1)
        stats = evidence.features(obs).sum(0, keepdim=True)
        ours = evidence.log_evidence(stats, torch.tensor([float(n)], dtype=D))[0]
        y = obs.log() @ helmert_basis(3, D, "cpu").T
        i = torch.arange(n, dtype=D)
        corr = rho ** (i[:, None] - i[None, :]).abs()
        for c in range(3):
            per_draw = [
                torch.distributions.MultivariateNormal(
                    draws["loc"][s, c].repeat(n),
                    torch.kron(torch.ones(n, n, dtype=D), draws["between"][s, c])
                    + torch.kron(corr, draws["within"][s]),
                ).log_prob(y.reshape(-1))
                for s in range(2)
            ]
            ref = torch.logsumexp(torch.stack(per_draw), 0) - math.log(2)
            assert float(ours[c]) == pytest.approx(float(ref), abs=1e-9), (n, c)


def test_a_lagged_filter_streams_as_it_batches_and_takes_the_posteriors_correlation():
    post = _sequence_posterior(0.7)
    filt = hbni_pyro.HBNIFilter(post)
    assert filt.frame_correlation == 0.7 and filt.lagged and "frame_correlation=0.700" in repr(filt)
    streams = post.sample_streams(2, 3, 9, seed=1)
    batch = filt.run(streams)
    for b in range(3):
        filt.reset()
        steps = torch.stack([filt.update(o) for o in streams[b]])
        torch.testing.assert_close(steps, batch[b], rtol=0, atol=1e-12)
    exchangeable = hbni_pyro.HBNIFilter(post, frame_correlation=0.0)
    assert not exchangeable.lagged
    # n identical frames: their look is that frame, and they count as n_eff = 1 + (n - 1)(1 - rho) / (1 + rho)
    frame = streams[0, :1]
    n_eff = 1 + 8 * 0.3 / 1.7
    expected = exchangeable.posterior(n_eff * exchangeable.features(frame), torch.tensor([n_eff], dtype=D))
    torch.testing.assert_close(filt.run(frame.expand(9, -1).unsqueeze(0))[0, -1], expected[0], rtol=0, atol=1e-12)


def test_filter_refuses_a_correlation_its_model_cannot_use():
    with pytest.raises(ValueError, match="frame_correlation"):
        hbni_pyro.HBNIFilter(_sequence_posterior(), frame_correlation=1.0)
    theta = torch.ones(1, 4, 3, dtype=D)
    ones = torch.ones(1, 4, dtype=D)
    paper = hbni_pyro.posterior.posterior_from_samples(
        {"theta": theta, "kappa": ones, "gamma": ones}, torch.full((3,), 1 / 3), hbni_pyro.HyperPrior()
    )
    with pytest.raises(ValueError, match="temper: a filter with frame_correlation 0.4 counts correlated frames"):
        hbni_pyro.HBNIFilter(_sequence_posterior(0.4), temper=0.5)
    assert hbni_pyro.HBNIFilter(_sequence_posterior(0.4), temper=0.5, frame_correlation=0.0).temper == 0.5
    with pytest.raises(ValueError, match="'paper' model's filter takes none"):
        hbni_pyro.HBNIFilter(paper, frame_correlation=0.5)
    assert not hbni_pyro.HBNIFilter(paper).lagged
