"""The sequence model's compiled per-sequence loops against their torch oracle, on one sampler state."""

import pytest
import torch

from hbni_pyro import SequenceMetropolis, as_outputs, sample_outputs
from hbni_pyro.models.sequence.steps import (
    GROUPED_LOOKS,
    between_data,
    class_log_probs,
    class_totals,
    draw_classes,
    draw_looks,
    look_factors,
    look_products,
    within_data,
)
from hbni_pyro.models import sequence_stats


def _kernel(num_classes: int, lengths: list[int], datasets: int, noise: float = 2.0) -> SequenceMetropolis:
    """A sampler set up on ``datasets`` copies of unlabelled sequences of the given lengths, each class in turn
    (classes' noise levels from ``noise`` to 4 times it)."""
    g = torch.Generator().manual_seed(0)
    ids = torch.cat([torch.full((n,), k) for k, n in enumerate(lengths)])
    classes = torch.arange(len(lengths)) % num_classes
    theta = torch.linspace(noise, 4 * noise, num_classes, dtype=torch.float64)
    obs = as_outputs(sample_outputs(theta, classes[ids], g))
    stats = sequence_stats(obs, ids, torch.full_like(ids, -1), len(lengths))
    kernel = SequenceMetropolis(num_chains=3 * datasets, seed=1)
    kernel.setup(5, type(stats)(*(t.expand((datasets,) + t.shape) for t in stats)))
    return kernel


@pytest.mark.parametrize(
    "num_classes, lengths",
    [(4, [5, 9] * 30), (4, list(range(2, 12)) * 6)],
    ids=["grouped", "gathered"],  # 8 (class, count) groups, then 40 > GROUPED_LOOKS: both torch paths
)
def test_compiled_loops_match_torch(num_classes, lengths):
    assert (len(set(lengths)) * num_classes > GROUPED_LOOKS) == (len(set(lengths)) > 2)
    kernel = _kernel(num_classes, lengths, datasets=2)
    state, stats = kernel.state, kernel.stats
    c = draw_classes(state, stats, kernel.log_prior, torch.Generator().manual_seed(2))
    factors = look_factors(state, stats, c)
    z = torch.randn(c.shape + state.loc.shape[-1:], generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    looks = [look_products(factors, c, z, compiled=flag) for flag in (True, False)]
    torch.testing.assert_close(looks[0], looks[1], rtol=1e-10, atol=1e-10)
    moved = state._replace(c=c, look=looks[0])
    steps = (
        lambda flag: between_data(moved, compiled=flag),
        lambda flag: class_totals(c, moved.look, num_classes, compiled=flag),
        lambda flag: within_data(moved, stats, compiled=flag),
    )
    for step in steps:
        fast, oracle = step(True), step(False)
        for a, b in zip(fast, oracle, strict=True):
            assert a.shape == b.shape
            torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-9)


def test_compiled_looks_follow_their_conditional():
    """Whitened by their conditional's mean and Cholesky factor, 2 datasets x 3 chains x 600 compiled looks are
    standard normal: mean and variance of every coordinate within 5 standard errors."""
    kernel = _kernel(3, [4, 7] * 300, datasets=2)
    state, stats = kernel.state, kernel.stats
    c = draw_classes(state, stats, kernel.log_prior, torch.Generator().manual_seed(2))
    look = draw_looks(state, stats, c, torch.Generator().manual_seed(4), compiled=True)
    factors = look_factors(state, stats, c)
    mean = look_products(factors, c, torch.zeros_like(look), compiled=False)
    tril = factors.tril.gather(-3, factors.group[..., None, None].expand(c.shape + factors.tril.shape[-2:]))
    w = torch.linalg.solve_triangular(tril, (look - mean).unsqueeze(-1), upper=False).squeeze(-1).reshape(-1, 2)
    n = w.shape[0]
    assert (w.mean(0).abs() < 5 / n**0.5).all()
    assert ((w.var(0) - 1).abs() < 5 * (2 / n) ** 0.5).all()
    again = draw_looks(state, stats, c, torch.Generator().manual_seed(4), compiled=True)
    assert torch.equal(look, again)


def test_compiled_classes_follow_their_conditional():
    """The compiled class draw of 2 datasets x 3 chains x 120 sequences (a third labelled), 400 times: every
    labelled sequence keeps its label, and every unknown one's class frequencies match ``softmax(class_log_probs)``
    (the squared standardised errors of the cells with probability in (0.05, 0.95) average 1 within 5 standard
    errors of that mean); the same generator seed gives the same draws."""
    kernel = _kernel(3, [1, 2] * 60, datasets=2, noise=0.3)
    state, stats = kernel.state, kernel.stats
    labels = torch.where(torch.arange(120) % 3 == 0, torch.arange(120) % 3, -1).expand(2, 1, 120)
    stats = stats._replace(labels=labels)
    g = torch.Generator().manual_seed(5)
    draws = torch.stack([draw_classes(state, stats, kernel.log_prior, g, compiled=True) for _ in range(400)])
    known = labels[0, 0] >= 0
    assert torch.equal(draws[..., known], labels[..., known].expand(draws[..., known].shape))
    p = torch.softmax(class_log_probs(stats, state, kernel.log_prior), -1)[..., ~known, :]
    freq = torch.nn.functional.one_hot(draws, 3).double().mean(0)[..., ~known, :]
    cells = (p > 0.05) & (p < 0.95)
    z2 = ((freq - p) ** 2 / (p * (1 - p) / 400))[cells]
    assert z2.numel() > 300 and abs(float(z2.mean()) - 1) < 5 * (2 / z2.numel()) ** 0.5
    again = draw_classes(state, stats, kernel.log_prior, torch.Generator().manual_seed(5), compiled=True)
    assert torch.equal(again, draws[0])
