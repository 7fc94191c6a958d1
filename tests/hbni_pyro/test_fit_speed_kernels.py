"""The compiled class move of the paper's model against exact enumeration and the torch move; seeded determinism."""

from __future__ import annotations

import numpy as np
import torch

from hbni_pyro.distributions import lifted_normaliser
from hbni_pyro.mcmc import MHState, frame_data, sufficient_stats, update_classes
from hbni_pyro.mcmc.class_move_numba import class_move_stats

M, N, CHAINS, STEPS = 3, 4, 20000, 40
OBS = torch.tensor([[0.7, 0.2, 0.1], [0.1, 0.3, 0.6], [0.34, 0.33, 0.33], [0.05, 0.9, 0.05]], dtype=torch.float64)
THETA = torch.tensor([2.0, 5.0, 1.0], dtype=torch.float64)
LOG_PRIOR = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64).log()


def _exact() -> torch.Tensor:
    """``(N, M)`` ``p(c_i = k | o_i, theta)`` by enumeration of the classes."""
    log_p = lifted_normaliser(THETA, M) + LOG_PRIOR + THETA * OBS.log()
    return torch.softmax(log_p, -1)


def _compiled(c: np.ndarray, seed: int, iteration: int, labels: np.ndarray | None = None) -> tuple:
    """One compiled move of classes ``c (1, N, chains)``."""
    data = frame_data(OBS, torch.full((N,), -1), LOG_PRIOR)
    arrays = [
        np.ascontiguousarray(t.numpy()[None]) for t in (data.log_obs, data.log_proposal, data.alias_prob, data.alias)
    ]
    labels = np.full((1, N), -1, dtype=np.int64) if labels is None else labels
    offset = (lifted_normaliser(THETA, M) + LOG_PRIOR).expand(1, c.shape[2], M).contiguous().numpy()
    theta = THETA.expand(1, c.shape[2], M).contiguous().numpy()
    counts = np.zeros((1, N, M))
    out = class_move_stats(
        c, labels, *arrays[:1], *arrays[1:], offset, theta, 0.5, np.uint64(seed), np.int64(iteration), counts, True
    )
    return out + (counts,)


def _tolerance(p: torch.Tensor) -> torch.Tensor:
    """Five Monte Carlo standard errors of a frequency over independent chains."""
    return 5 * (p * (1 - p) / CHAINS).sqrt() + 1e-12


def test_compiled_move_keeps_the_exact_conditional() -> None:
    c = np.zeros((1, N, CHAINS), dtype=np.int64)
    for t in range(STEPS):
        _compiled(c, 3, t)
    freq = torch.nn.functional.one_hot(torch.from_numpy(c[0].T), M).double().mean(0)
    exact = _exact()
    assert ((freq - exact).abs() <= _tolerance(exact)).all(), (freq, exact)


def test_torch_move_agrees_with_the_exact_conditional() -> None:
    data = frame_data(OBS, torch.full((N,), -1), LOG_PRIOR)
    state = MHState(
        torch.zeros(CHAINS, N, dtype=torch.long),
        THETA.log().expand(CHAINS, M),
        torch.zeros(CHAINS),
        torch.zeros(CHAINS),
    )
    g = torch.Generator().manual_seed(0)
    for _ in range(STEPS):
        update_classes(state, data, 0.5, g)
    freq = torch.nn.functional.one_hot(state.c, M).double().mean(0)
    exact = _exact()
    assert ((freq - exact).abs() <= _tolerance(exact)).all(), (freq, exact)


def test_compiled_statistics_labels_and_counts() -> None:
    c = np.random.default_rng(0).integers(0, M, (1, N, 8))
    labels = np.array([[-1, 2, -1, 0]])
    c[0, 1], c[0, 3] = 2, 0
    counts, sums, accepted, recorded = _compiled(c, 1, 0, labels)
    want_counts, want_sums = sufficient_stats(torch.from_numpy(c).transpose(1, 2), OBS.log())
    assert np.array_equal(counts, want_counts.numpy()) and np.allclose(sums, want_sums.numpy())
    assert (c[0, 1] == 2).all() and (c[0, 3] == 0).all()
    assert np.array_equal(recorded[0], torch.nn.functional.one_hot(torch.from_numpy(c[0]), M).sum(1).double().numpy())
    assert accepted.shape == (1, 8) and (accepted >= 0).all()


def test_compiled_move_is_seeded() -> None:
    start = np.random.default_rng(1).integers(0, M, (1, N, 64))
    a, b, d = start.copy(), start.copy(), start.copy()
    _compiled(a, 5, 7)
    _compiled(b, 5, 7)
    _compiled(d, 6, 7)
    assert np.array_equal(a, b) and not np.array_equal(a, d)


def test_frame_move_is_the_same_for_either_storage_of_the_classes() -> None:
    """The kernel's classes are stored outputs-major; classes stored chains-major get the same move, in place."""
    from hbni_pyro.mcmc import FrameData

    frames = FrameData(OBS.unsqueeze(0), None, LOG_PRIOR)
    start = torch.from_numpy(np.random.default_rng(2).integers(0, M, (1, 6, N)))
    log_theta = THETA.log().expand(1, 6, M)
    moved = []
    for c in (start.clone(), FrameData.outputs_major(start)):
        stats = frames.compiled_move(c, log_theta, 0.5, 9, 3, False)
        moved.append((c, stats))
    (a, (acc_a, (n_a, s_a))), (b, (acc_b, (n_b, s_b))) = moved
    assert b.stride() == (N * 6, 1, 6) and a.is_contiguous()
    assert torch.equal(a, b) and not torch.equal(a, start) and acc_a == acc_b > 0
    assert torch.equal(n_a, n_b) and torch.equal(s_a, s_b)
