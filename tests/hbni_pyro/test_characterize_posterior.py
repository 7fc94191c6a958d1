"""The generative planning model: characterize on a posterior simulates its posterior predictive.

Each simulated stream draws one theta from the posterior's draws, then i.i.d. outputs given it, so the
table is the mixture, over the draws, of the tables each draw gives alone.
"""

import pytest
import torch

import hbni_pyro
from hbni_pyro.models import site_shapes

from hbni_stubs import DrawsPosterior

DT = torch.float64


def test_a_posterior_table_is_the_mixture_of_its_draws_tables():
    """Two draws (a noisy and a clean classifier): every confusion cell and mean frame count within 5 s.e. of
    the mixture of the two single-draw tables (n = 6000 streams per class each; s.e. from all three's variances)."""
    noisy, clean = torch.tensor([0.8, 1.5, 3.0], dtype=DT), torch.tensor([6.0, 9.0, 20.0], dtype=DT)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.9, max_frames=8)
    n = 6000
    mixed = hbni_pyro.characterize(process, DrawsPosterior(torch.stack([noisy, clean])), n, seed=0)
    a = hbni_pyro.characterize(process, noisy, n, seed=1)
    b = hbni_pyro.characterize(process, clean, n, seed=2)
    expect = 0.5 * (a.confusion + b.confusion)
    var = (
        mixed.confusion * (1 - mixed.confusion)
        + 0.25 * (a.confusion * (1 - a.confusion) + b.confusion * (1 - b.confusion))
    ) / n
    assert ((mixed.confusion - expect).abs() <= 5 * var.sqrt() + 1e-12).all()
    frames = 0.5 * (a.mean_frames + b.mean_frames)
    support = torch.arange(1, 9, dtype=DT)

    def frames_var(model):  # (M,) variance of frames used per class
        return model.frames_pmf @ support**2 - model.mean_frames**2

    se = ((frames_var(mixed) + 0.25 * (frames_var(a) + frames_var(b))) / n).sqrt()
    assert ((mixed.mean_frames - frames).abs() <= 5 * se).all()
    assert not torch.allclose(a.confusion, b.confusion, atol=0.05)  # the two draws do differ
    assert mixed.info["generative"] == "posterior predictive" and mixed.info["num_streams"] == n


def _posterior(model, **sites):
    """One-chain posterior whose every site is the given draws ``(S, ...)`` (the others' values do not matter)."""
    M = 3
    samples = {k: torch.as_tensor(v, dtype=DT).unsqueeze(0) for k, v in sites.items()}
    S = next(iter(samples.values())).shape[1]
    for k, shape in site_shapes(model, M).items():
        samples.setdefault(k, torch.ones((1, S) + shape, dtype=DT))
    return hbni_pyro.HBNIPosterior(samples, torch.full((M,), 1 / M, dtype=DT), model=model)


def test_a_paper_posterior_gives_the_same_table_as_its_theta_draws():
    """The generative planning model of a paper posterior is unchanged: bit for bit the table of its theta draws."""
    theta = torch.tensor([[0.8, 1.5, 3.0], [6.0, 9.0, 20.0], [2.0, 2.0, 2.0]], dtype=DT)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.9, max_frames=6)
    a = hbni_pyro.characterize(process, _posterior("paper", theta=theta), 300, seed=4)
    b = hbni_pyro.characterize(process, DrawsPosterior(theta), 300, seed=4)
    assert torch.equal(a.joint, b.joint) and torch.equal(a.timed_out, b.timed_out)


def test_a_confusion_posterior_with_uniform_confusions_gives_the_paper_table():
    """``beta = 1`` everywhere is the paper's model: every cell and mean frame count within 5 s.e. (n = 4000 per class)."""
    theta = torch.tensor([[0.8, 1.5, 3.0]], dtype=DT)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.9, max_frames=6)
    n = 4000
    conf = hbni_pyro.characterize(process, _posterior("confusion", theta=theta, beta=torch.ones(1, 3, 3)), n, seed=0)
    paper = hbni_pyro.characterize(process, theta[0], n, seed=1)
    var = (conf.confusion * (1 - conf.confusion) + paper.confusion * (1 - paper.confusion)) / n
    assert ((conf.confusion - paper.confusion).abs() <= 5 * var.sqrt() + 1e-12).all()
    assert conf.info["generative"] == "posterior predictive (confusion model)"


def test_a_confusion_posterior_simulates_its_confusions():
    """Class 0 confused with class 1 (``beta_01 = 4``), not with 2: its wrong labels are nearly all 1."""
    theta = torch.tensor([[1.0, 6.0, 6.0]], dtype=DT)
    beta = torch.ones(1, 3, 3, dtype=DT)
    beta[0, 0, 1] = 4.0
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.9, max_frames=4)
    table = hbni_pyro.characterize(process, _posterior("confusion", theta=theta, beta=beta), 2000, seed=0)
    assert table.confusion[0, 1] > 0.2 and table.confusion[0, 1] > 5 * table.confusion[0, 2]


def test_a_sequence_posterior_simulates_streams_that_share_a_look():
    """Each stream has its own look, shared by its frames: with a wide spread of looks and tight frames, the
    argmax after 10 frames is right far less often (about 0.58) than on 10 i.i.d. frames of the same marginal
    (about 0.9); the gap must exceed 10 binomial s.e. (n = 1000 per class, s.e. <= 0.016 each)."""
    d, n, T = 2, 1000, 10
    loc = torch.tensor([[[1.0, 0.5], [-1.0, 0.5], [0.0, -1.0]]], dtype=DT)
    between = (3.0 * torch.eye(d, dtype=DT)).expand(1, 3, d, d)
    within = (0.05 * torch.eye(d, dtype=DT)).unsqueeze(0)
    post = _posterior("sequence", loc=loc, between=between, within=within)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.MaxOfMeanFilter(3), threshold=0.999, max_frames=T)
    table = hbni_pyro.characterize(process, post, n, seed=0)
    truth = torch.arange(3).repeat_interleave(n)
    g = torch.Generator().manual_seed(0)
    again = hbni_pyro.tabulate(process, torch.cat([post.sample_streams(c, n, T, generator=g) for c in range(3)]), truth)
    assert torch.equal(table.joint, again.joint)  # the posterior's own predictive, class by class, one generator
    assert table.info["generative"] == "posterior predictive (sequence model)"
    iid = hbni_pyro.tabulate(
        process, torch.cat([post.sample_streams(c, n * T, 1, seed=1).reshape(n, T, 3) for c in range(3)]), truth
    )
    se = ((table.accuracy * (1 - table.accuracy) + iid.accuracy * (1 - iid.accuracy)) / n).sqrt()
    assert (iid.accuracy - table.accuracy > 10 * se).all()


def test_a_posterior_over_other_classes_is_refused():
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(2), threshold=0.9, max_frames=4)
    with pytest.raises(ValueError, match="generative: expected a posterior over 2 classes, got 3"):
        hbni_pyro.characterize(process, _posterior("confusion", theta=torch.ones(1, 3)), 10, seed=0)
    with pytest.raises(TypeError, match="generator: expected a torch.Generator or None, got int"):
        _posterior("paper", theta=torch.ones(1, 3)).sample_streams(0, 2, 2, generator=3)
