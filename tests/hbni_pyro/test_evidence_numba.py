"""The sequence model's compiled evidence (CPU) against its torch path, the oracle: the same values up to rounding,
and a block's value the same bits alone as in any batch."""

import math

import pytest
import torch

from hbni_pyro.models import SequenceEvidence

D = torch.float64


def _draws(S: int, M: int, d: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(S, d, d, generator=g, dtype=D)
    b = torch.randn(S, M, d, d, generator=g, dtype=D)
    return {
        "loc": 2 * torch.randn(S, M, d, generator=g, dtype=D),
        "between": b @ b.transpose(-1, -2) + 0.2 * torch.eye(d, dtype=D),
        "within": a @ a.transpose(-1, -2) + 0.4 * torch.eye(d, dtype=D),
    }


def _blocks(evidence: SequenceEvidence, K: int, frames: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Summed features of the first ``n`` frames of ``K`` random streams, ``n`` from 1 to ``frames`` (mixed)."""
    g = torch.Generator().manual_seed(seed)
    obs = torch.softmax(1.5 * torch.randn(K, frames, evidence.num_classes, generator=g, dtype=D), -1)
    counts = torch.randint(1, frames + 1, (K,), generator=g).to(D)
    stats = (evidence.features(obs).cumsum(1))[torch.arange(K), counts.long() - 1]
    return stats, counts


@pytest.mark.parametrize("rho", [0.0, 0.7, -0.4])
@pytest.mark.parametrize("S, M", [(3, 3), (900, 6)])
def test_compiled_evidence_is_the_torch_evidence(rho, S, M):
    compiled = SequenceEvidence(_draws(S, M, M - 1, seed=S), correlation=rho)
    oracle = SequenceEvidence(_draws(S, M, M - 1, seed=S), correlation=rho)
    oracle._compiled = None
    stats, counts = _blocks(compiled, 40, 30, seed=M)
    ours, theirs = compiled.log_evidence(stats, counts), oracle.log_evidence(stats, counts)
    assert ours.shape == (40, M) and ours.dtype == D
    scale = theirs.abs().clamp_min(1.0)
    assert float(((ours - theirs).abs() / scale).max()) < 1e-12
    tempered = compiled.log_evidence(0.4 * stats, 0.4 * counts)  # a temper makes counts fractional (NaN where the
    # anticorrelated weight of under one frame turns negative, on both paths)
    expected = oracle.log_evidence(0.4 * stats, 0.4 * counts)
    torch.testing.assert_close(tempered, expected, rtol=1e-12, atol=1e-10, equal_nan=True)


def test_a_blocks_compiled_evidence_does_not_depend_on_the_batch():
    evidence = SequenceEvidence(_draws(500, 4, 3, seed=2), correlation=0.5)
    stats, counts = _blocks(evidence, 25, 12, seed=3)
    batch = evidence.log_evidence(stats, counts)
    for k in range(25):
        assert torch.equal(evidence.log_evidence(stats[k : k + 1], counts[k : k + 1]), batch[k : k + 1])
    order = torch.randperm(25, generator=torch.Generator().manual_seed(4))
    assert torch.equal(evidence.log_evidence(stats[order], counts[order]), batch[order])


def test_far_apart_draws_keep_a_finite_evidence():
    """One draw dominating the others by far more than exp(700): the sum keeps it alone, as logsumexp does."""
    draws = _draws(4, 3, 2, seed=5)
    draws["loc"][1:] += 200.0
    evidence = SequenceEvidence(draws)
    stats, counts = _blocks(evidence, 6, 5, seed=6)
    out = evidence.log_evidence(stats, counts)
    assert torch.isfinite(out).all()
    evidence._compiled = None
    torch.testing.assert_close(out, evidence.log_evidence(stats, counts), rtol=1e-12, atol=1e-9)
    assert math.isfinite(float(out.max()))
