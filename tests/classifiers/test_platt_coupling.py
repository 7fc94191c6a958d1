"""Platt scaling against scikit-learn, pairwise coupling against libsvm's iteration and closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from classifiers import fit_platt, pairwise_coupling, platt_predict

calibration = pytest.importorskip("sklearn.calibration")


def _scores(seed: int, n: int = 300):
    rng = np.random.default_rng(seed)
    y = rng.random(n) < rng.uniform(0.2, 0.8)
    f = rng.normal(size=n) * rng.uniform(0.5, 2) + np.where(y, 1.0, -1.0) * rng.uniform(0.2, 2.5)
    return f, y


@pytest.mark.parametrize("seed", range(6))
def test_platt_matches_sklearn_sigmoid_calibration(seed):
    f, y = _scores(seed)
    a_ref, b_ref = calibration._sigmoid_calibration(f, y.astype(int))
    a, b = fit_platt(torch.tensor(f), torch.tensor(y))
    assert float(a) == pytest.approx(a_ref, abs=1e-3)
    assert float(b) == pytest.approx(b_ref, abs=1e-3)


def test_platt_batched_equals_single_and_masks():
    sets = [_scores(s, 200) for s in range(3)]
    f = torch.tensor(np.stack([s[0] for s in sets]))
    y = torch.tensor(np.stack([s[1] for s in sets]))
    mask = torch.ones_like(y)
    mask[1, 150:] = False  # problem 1 uses only its first 150 examples
    a, b = fit_platt(f, y, mask)
    for k in range(3):
        n = 150 if k == 1 else 200
        a1, b1 = fit_platt(f[k, :n], y[k, :n])
        assert float(a[k]) == pytest.approx(float(a1), abs=1e-8)
        assert float(b[k]) == pytest.approx(float(b1), abs=1e-8)
    p = platt_predict(f.T, a, b)
    assert p.shape == (200, 3) and ((p > 0) & (p < 1)).all()
    with pytest.raises(ValueError, match="positive"):
        fit_platt(f, y[:, :10])


def _libsvm_multiclass_probability(r: np.ndarray, eps: float) -> np.ndarray:
    """libsvm's fixed-point iteration (svm.cpp, multiclass_probability) with a chosen tolerance."""
    k = r.shape[0]
    q = np.zeros((k, k))
    for t in range(k):
        for j in range(k):
            if j != t:
                q[t, t] += r[j, t] ** 2
                q[t, j] = -r[j, t] * r[t, j]
    p = np.full(k, 1.0 / k)
    for _ in range(10000):
        qp = q @ p
        pqp = p @ qp
        if np.abs(qp - pqp).max() < eps:
            break
        for t in range(k):
            diff = (-qp[t] + pqp) / q[t, t]
            p[t] += diff
            pqp = (pqp + diff * (diff * q[t, t] + 2 * qp[t])) / (1 + diff) ** 2
            qp = (qp + diff * q[t]) / (1 + diff)
            p /= 1 + diff
    return p


@pytest.mark.parametrize("m", [2, 3, 6])
def test_coupling_matches_libsvm_and_sums_to_one(m):
    rng = np.random.default_rng(m)
    upper = rng.uniform(0.02, 0.98, size=(50, m, m))
    r = np.triu(upper, 1) + np.tril(1 - upper.transpose(0, 2, 1), -1)
    p = pairwise_coupling(torch.tensor(r))
    assert p.shape == (50, m)
    assert torch.allclose(p.sum(-1), torch.ones(50, dtype=p.dtype), atol=1e-12)
    assert (p >= 0).all()
    ref = np.stack([_libsvm_multiclass_probability(ri, 1e-12) for ri in r])
    np.testing.assert_allclose(p.numpy(), ref, atol=1e-6)


def test_coupling_recovers_consistent_pairwise_probabilities():
    p = torch.tensor([[0.5, 0.3, 0.2], [0.05, 0.05, 0.9], [0.25, 0.25, 0.5]], dtype=torch.float64)
    r = p[:, :, None] / (p[:, :, None] + p[:, None, :])
    assert torch.allclose(pairwise_coupling(r), p, atol=1e-12)
    with pytest.raises(ValueError, match="r"):
        pairwise_coupling(torch.zeros(3, 2, 3))
