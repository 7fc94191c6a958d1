"""Adapting the sequence model to a new place: recovery of known noise from unlabelled streams simulated from the
model, the shift prior's and the class mix's exact draws, the swap move, determinism and every error path."""

import math

import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_sequences
from hbni_pyro.models.sequence.steps import SequenceState
from hbni_pyro.models.sequence.shift_steps import draw_prevalence, draw_shift, relabel, slot_scores
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.posterior.posterior import posterior_from_samples
from hbni_pyro.models.sequence.program import look_prior_mean, sequence_log_lik, sequence_stats
from hbni_pyro.models.sequence import draw_prior

M, D = 4, 3


def _place(seed: int = 0) -> dict[str, torch.Tensor]:
    """The old place's sequence-model parameters: class looks at their vertices, the rest from the prior."""
    g = torch.Generator().manual_seed(seed)
    params = {k: v[0] for k, v in draw_prior(HyperPrior(), M, 1, g).items()}
    params["loc"] = look_prior_mean(M, 1.5)
    return params


def _posterior(params: dict[str, torch.Tensor]) -> hbni_pyro.HBNIPosterior:
    """A posterior whose every draw is ``params`` (2 chains of 2 draws), named."""
    samples = {k: v.expand((2, 2) + v.shape).clone() for k, v in params.items()}
    return posterior_from_samples(samples, torch.full((M,), 1 / M), HyperPrior(), "sequence").named(list("abcd"))


def _new_place(old: dict[str, torch.Tensor], prior: hbni_pyro.ShiftPrior, g: torch.Generator) -> dict:
    """New-place parameters drawn from the shift prior around ``old``: a shared scale and offset, then each class."""
    new = dict(old)
    scale, offset = 0.85, torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    new["loc"] = scale * prior.anchor + offset + prior.shift_sd * torch.randn(M, D, generator=g, dtype=torch.float64)
    new["within"] = 1.3 * old["within"]
    return new | {"scale": torch.tensor(scale), "offset": offset}


def _streams(params: dict, classes: torch.Tensor, frames: int, g: torch.Generator) -> tuple:
    seqs = sample_sequences(params["loc"], params["between"], params["within"], classes, frames, g)
    return seqs.reshape(-1, M), torch.arange(len(classes)).repeat_interleave(frames)


def test_adapt_recovers_a_new_place_from_unlabelled_streams():
    """240 unlabelled sequences of 20 frames, a skewed class mix, from parameters drawn from the shift prior: every
    class mean, the shared scale and the class mix lie within 4.5 posterior sd of the truth (one coordinate in
    about 150 000 falls outside by chance; 20 quantities here), and the sequences' classes are recovered."""
    g = torch.Generator().manual_seed(1)
    old = _place()
    posterior = _posterior(old)
    new = _new_place(old, hbni_pyro.ShiftPrior.from_posterior(posterior), g)
    classes = torch.multinomial(torch.tensor([0.4, 0.3, 0.2, 0.1]), 240, replacement=True, generator=g)
    obs, ids = _streams(new, classes, 20, g)
    fitted = hbni_pyro.adapt(
        posterior, obs, sequence_ids=ids, num_chains=4, num_samples=100, warmup_steps=100, progress=False
    )
    draws = fitted.draws()["loc"]
    z = (draws.mean(0) - new["loc"]) / draws.std(0)
    assert z.abs().max() < 4.5, z
    sites = fitted.info["sites"]
    scale = sites["shift_scale"]
    assert abs(scale["mean"] - 0.85) < 4.5 * scale["sd"]
    mix = torch.bincount(classes, minlength=M).double() / len(classes)
    prevalence = torch.tensor(sites["prevalence"]["mean"]), torch.tensor(sites["prevalence"]["sd"])
    assert ((prevalence[0] - mix).abs() < 4.5 * prevalence[1]).all()
    fitted_right = (fitted.label_probs.reshape(240, 20, M)[:, 0].argmax(-1) == classes).double().mean()
    stats = sequence_stats(obs, ids, torch.full_like(ids, -1), 240)
    best = sequence_log_lik(stats, {k: new[k] for k in ("loc", "between", "within")}, mix).argmax(-1)
    best_right = float((best == classes).double().mean())  # the true parameters' classification
    assert fitted_right >= best_right - 3 * (best_right * (1 - best_right) / 240) ** 0.5 - 1 / 240
    assert fitted.class_names == posterior.class_names and fitted.info["shift_prior"]["shift_sd"] == 0.2
    assert torch.equal(fitted.class_prior, posterior.class_prior)  # the filter's prior stays the old one


def test_adapt_is_seeded_and_takes_labels():
    g = torch.Generator().manual_seed(2)
    old = _place()
    posterior = _posterior(old)
    classes = torch.arange(M).repeat(10)
    obs, ids = _streams(old, classes, 8, g)
    labels = torch.where(ids < 8, classes[ids], -1)  # the first 8 sequences labelled
    fits = [
        hbni_pyro.adapt(
            posterior,
            obs,
            labels,
            sequence_ids=ids,
            num_chains=2,
            num_samples=20,
            warmup_steps=10,
            seed=3,
            progress=False,
        )
        for _ in range(2)
    ]
    for site, value in fits[0].samples.items():
        assert torch.equal(value, fits[1].samples[site])
    assert torch.equal(fits[0].label_probs[ids < 8], torch.nn.functional.one_hot(classes[ids[ids < 8]], M).double())
    fixed = hbni_pyro.adapt(
        posterior, obs, sequence_ids=ids, prevalence=None, num_chains=2, num_samples=5, warmup_steps=5, progress=False
    )
    assert "prevalence" not in fixed.info["sites"] and fixed.info["prevalence_concentration"] is None


def test_adapt_refuses_bad_input():
    old = _place()
    posterior = _posterior(old)
    obs, ids = _streams(old, torch.arange(M), 3, torch.Generator().manual_seed(0))
    fit = dict(sequence_ids=ids, num_chains=2, num_samples=2, warmup_steps=2, progress=False)
    with pytest.raises(TypeError, match="posterior: expected an HBNIPosterior"):
        hbni_pyro.adapt(posterior.samples, obs, **fit)
    paper = hbni_pyro.fit(obs, num_chains=2, num_samples=2, warmup_steps=2, progress=False)
    with pytest.raises(ValueError, match="posterior: expected a fitted 'sequence' model"):
        hbni_pyro.adapt(paper, obs, **fit)
    with pytest.raises(ValueError, match="obs: expected rows of width M = 4"):
        hbni_pyro.adapt(posterior, obs[:, :3] / obs[:, :3].sum(-1, keepdim=True), **fit)
    with pytest.raises(ValueError, match="shift_sd"):
        hbni_pyro.adapt(posterior, obs, shift_sd=0.0, **fit)
    with pytest.raises(ValueError, match="prevalence"):
        hbni_pyro.adapt(posterior, obs, prevalence=-1.0, **fit)
    with pytest.raises(ValueError, match="sequence_ids"):
        hbni_pyro.adapt(posterior, obs, **(fit | {"sequence_ids": None}))
    with pytest.raises(ValueError, match="anchor: expected shape"):
        hbni_pyro.ShiftPrior(torch.zeros(4, 4))
    with pytest.raises(ValueError, match="anchor: expected finite"):
        hbni_pyro.ShiftPrior(torch.full((3, 2), math.nan))
    with pytest.raises(ValueError, match="class_names"):
        hbni_pyro.ShiftPrior(torch.zeros(3, 2), ("a", "b"))
    kernel = hbni_pyro.SequenceMetropolis(num_chains=2, shift_prior=hbni_pyro.ShiftPrior(torch.zeros(3, 2)))
    stats = sequence_stats(obs, ids, torch.full_like(ids, -1), M)
    with pytest.raises(ValueError, match="shift_prior: expected an anchor of 4 classes"):
        kernel.setup(0, stats)
    with pytest.raises(TypeError, match="shift_prior: expected a ShiftPrior"):
        hbni_pyro.SequenceMetropolis(num_chains=2, shift_prior=torch.zeros(4, 3))


def test_shift_and_prevalence_draws_match_their_conditionals():
    """The shared scale and offset given the class means: the Gaussian regression posterior in closed form (mean and
    covariance of 20 000 draws within 5 standard errors); the class mix given the classes: ``Dir(1 + counts)``."""
    prior = hbni_pyro.ShiftPrior(look_prior_mean(M, 1.5), shift_sd=0.3, scale_sd=0.5, offset_sd=2.0)
    a = prior.anchor
    loc = 0.8 * a + 0.1 + 0.05 * torch.arange(M * D, dtype=torch.float64).reshape(M, D)
    design = torch.cat([a.reshape(-1, 1), torch.eye(D, dtype=torch.float64).repeat(M, 1)], 1)  # (M d, 1 + d)
    prior_prec = torch.diag(torch.tensor([1 / 0.5**2] + [1 / 2.0**2] * D, dtype=torch.float64))
    prec = prior_prec + design.T @ design / 0.3**2
    cov = torch.linalg.inv(prec)
    mean = cov @ (
        prior_prec @ torch.tensor([1.0] + [0.0] * D, dtype=torch.float64) + design.T @ loc.reshape(-1) / 0.3**2
    )
    n = 20_000
    scale, offset = draw_shift(loc.expand(n, M, D), prior, torch.Generator().manual_seed(0))
    x = torch.cat([scale.unsqueeze(-1), offset], -1)
    sd = cov.diagonal().sqrt()
    assert ((x.mean(0) - mean).abs() < 5 * sd / n**0.5).all()
    assert (
        (torch.cov(x.T) - cov).abs() < 5 * (cov.diagonal()[:, None] * cov.diagonal()[None]).sqrt() * (2 / n) ** 0.5
    ).all()
    c = torch.tensor([0, 0, 0, 1, 2, 2]).expand(n, 6)
    p = draw_prevalence(c, M, 1.0, torch.Generator().manual_seed(1)).exp().squeeze(-2)
    alpha = torch.tensor([4.0, 2.0, 3.0, 1.0], dtype=torch.float64)
    expected = alpha / alpha.sum()
    var = expected * (1 - expected) / (alpha.sum() + 1)
    assert ((p.mean(0) - expected).abs() < 5 * (var / n).sqrt()).all()


def _state(params: dict, stats, chains: int, g: torch.Generator) -> SequenceState:
    K = stats.count.shape[-1]
    c = torch.randint(M, (1, chains, K), generator=g)
    look = stats.mean_y.expand(1, chains, K, D).clone()
    expand = lambda t: t.expand((1, chains) + t.shape).clone()  # noqa: E731
    return SequenceState(
        c,
        look,
        expand(params["loc"]),
        expand(params["between"]),
        expand(params["between_mean"]),
        torch.zeros(1, chains, dtype=torch.float64),
        expand(params["within"]),
    )


def test_relabel_restores_exchanged_classes_and_keeps_the_likelihood():
    """Classes 1 and 3 exchanged against the anchors: with no labels every chain swaps them back, the classes of
    the unlabelled sequences follow, and the unlabelled sequences' likelihood (classes summed out) is unchanged;
    labels that fit the exchanged state keep it."""
    g = torch.Generator().manual_seed(4)
    params = _place()
    obs, ids = _streams(params, torch.arange(M).repeat(6), 10, g)
    prior = hbni_pyro.ShiftPrior(params["loc"], shift_sd=0.2)
    swapped = dict(params, loc=params["loc"][[0, 3, 2, 1]], between=params["between"][[0, 3, 2, 1]])
    unlabelled = sequence_stats(obs, ids, torch.full_like(ids, -1), 24)
    stats = type(unlabelled)(*(t.unsqueeze(0).unsqueeze(0) for t in unlabelled))
    state = _state(swapped, stats, 5, g)
    moved, _, accepted = relabel(state, stats, prior.anchor, 0.2, None, g)
    assert int(accepted) == 5
    torch.testing.assert_close(moved.loc, params["loc"].expand(1, 5, M, D))
    assert torch.equal(moved.c, torch.tensor([0, 3, 2, 1])[state.c])
    p = torch.full((M,), 1 / M, dtype=torch.float64)
    lik = [
        torch.logsumexp(sequence_log_lik(stats, {k: getattr(s, k) for k in ("loc", "between", "within")}, p), -1).sum(
            -1
        )
        for s in (state, moved)
    ]
    torch.testing.assert_close(lik[0], lik[1])
    labels = torch.tensor([0, 3, 2, 1])[torch.arange(M).repeat(6)]  # the exchanged state's classes, known
    labelled = sequence_stats(obs, ids, labels[ids], 24)
    lab_stats = type(labelled)(*(t.unsqueeze(0).unsqueeze(0) for t in labelled))
    kept, _, accepted = relabel(
        _state(swapped, lab_stats, 5, g)._replace(c=labels.expand(1, 5, 24)), lab_stats, prior.anchor, 0.2, None, g
    )
    assert int(accepted) == 0 and torch.equal(kept.loc, swapped["loc"].expand(1, 5, M, D))
    scores = slot_scores(state, stats, prior.anchor, 0.2, None)
    assert scores.shape == (1, 5, M, M)
