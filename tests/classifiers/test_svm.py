"""The one-vs-one SVM head: optimality, agreement with scikit-learn's SVC, storage, determinism, errors."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from classifiers import OneVsOneSVC
from classifiers.svm import objective, train_squared_hinge

svm = pytest.importorskip("sklearn.svm")
metrics = pytest.importorskip("sklearn.metrics")


def test_solver_matches_generic_optimizer():
    """The Newton solution equals L-BFGS on the same primal objective, for a full and a masked problem."""
    optimize = pytest.importorskip("scipy.optimize")
    g = torch.Generator().manual_seed(0)
    x = torch.randn(80, 6, generator=g, dtype=torch.float64)
    y = torch.sign(x[:, 0] + 0.5 * torch.randn(80, generator=g, dtype=torch.float64))[None].repeat(2, 1)
    s = torch.ones_like(y)
    s[1, 40:] = 0
    w, b = train_squared_hinge(x, y, s, c=0.7)

    values = objective(w, b, x, y, s, 0.7)
    for q in range(2):

        def loss(theta, q=q):
            t = torch.tensor(theta, requires_grad=True)
            value = objective(t[None, :-1], t[-1:], x, y[q : q + 1], s[q : q + 1], 0.7)[0]
            value.backward()
            return value.item(), t.grad.numpy()

        ref = optimize.minimize(loss, np.zeros(7), jac=True, method="L-BFGS-B", options={"gtol": 1e-12, "ftol": 1e-15})
        assert values[q].item() == pytest.approx(ref.fun, rel=1e-9)
        np.testing.assert_allclose(torch.cat([w[q], b[q : q + 1]]).numpy(), ref.x, atol=1e-5)


def test_head_matches_sklearn_svc_on_backbone_features(standardized_features):
    x_tr, y_tr, x_te, y_te = standardized_features
    head = OneVsOneSVC(C=1.0).fit(x_tr, y_tr)
    p = head.predict_proba(x_te)
    assert isinstance(p, np.ndarray) and p.dtype == np.float64
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # SVC(probability=True) is deprecated in sklearn 1.9
        ref = svm.SVC(kernel="linear", probability=True, C=1.0, random_state=0).fit(x_tr, y_tr)
    p_ref = ref.predict_proba(x_te)
    acc, acc_ref = metrics.accuracy_score(y_te, head.predict(x_te)), metrics.accuracy_score(y_te, ref.predict(x_te))
    loss, loss_ref = metrics.log_loss(y_te, p), metrics.log_loss(y_te, p_ref)
    print(f"accuracy {acc:.3f} vs SVC {acc_ref:.3f}; log-loss {loss:.3f} vs SVC {loss_ref:.3f}")
    assert abs(acc - acc_ref) <= 0.02
    assert loss <= loss_ref + 0.05
    np.testing.assert_allclose(p.sum(1), 1.0, atol=1e-12)
    assert head.decision_function(x_te).shape == (len(y_te), 3)
    assert head.classes_.tolist() == [0, 1, 2] and head.n_features_in_ == x_tr.shape[1]
    assert torch.equal(head.proba(x_te), torch.from_numpy(p))  # the torch path the pipeline uses


def test_string_labels_save_load_and_determinism(tmp_path, standardized_features):
    x_tr, y_tr, x_te, _ = standardized_features
    names = np.array(["a", "b", "c"])[y_tr]
    head = OneVsOneSVC(C=0.5, seed=4).fit(x_tr, names)
    again = OneVsOneSVC(C=0.5, seed=4).fit(x_tr, names)
    assert np.array_equal(head.predict_proba(x_te), again.predict_proba(x_te))
    path = head.save(tmp_path / "head.safetensors")
    loaded = OneVsOneSVC.load(path)
    assert loaded.classes_.tolist() == ["a", "b", "c"] and loaded.classes_.dtype == head.classes_.dtype
    assert np.array_equal(loaded.predict_proba(x_te), head.predict_proba(x_te))
    assert np.array_equal(loaded.predict(x_te[:5]), head.predict(x_te[:5])) and head.predict(x_te[:5]).dtype.kind == "U"


def test_error_paths(tmp_path, standardized_features):
    x_tr, y_tr, _, _ = standardized_features
    with pytest.raises(ValueError, match="C"):
        OneVsOneSVC(C=0)
    with pytest.raises(ValueError, match="cv"):
        OneVsOneSVC(cv=1)
    with pytest.raises(RuntimeError, match="fit"):
        OneVsOneSVC().predict_proba(x_tr)
    with pytest.raises(ValueError, match="at least 2 classes"):
        OneVsOneSVC().fit(x_tr, np.zeros(len(x_tr)))
    with pytest.raises(ValueError, match="cv=5"):
        OneVsOneSVC().fit(x_tr[:8], np.array([0, 1] * 4))
    with pytest.raises(ValueError, match="y"):
        OneVsOneSVC().fit(x_tr, y_tr[:-1])
    with pytest.raises(ValueError, match="NaN"):
        OneVsOneSVC().fit(np.full((10, 2), np.nan), np.arange(10) % 2)
    with pytest.raises(TypeError, match="X"):
        OneVsOneSVC().fit("features", [0])
    with pytest.raises(ValueError, match="continuous"):
        OneVsOneSVC().fit(x_tr, np.linspace(0, 1, len(x_tr)))
    with pytest.raises(ValueError, match="target y is None"):
        OneVsOneSVC().fit(x_tr, None)
    head = OneVsOneSVC().fit(x_tr, y_tr)
    with pytest.raises(ValueError, match="features"):
        head.predict_proba(x_tr[:, :10])
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00" * 40)
    with pytest.raises(ValueError, match="is not a readable model file"):
        OneVsOneSVC.load(bad)
    with pytest.raises(FileNotFoundError):
        OneVsOneSVC.load(tmp_path / "missing.safetensors")
    from hbni_infra.tensorfile import save_tensors

    save_tensors(tmp_path / "other.safetensors", "something.else", {"a": torch.zeros(1)}, {})
    with pytest.raises(ValueError, match="holds something.else, expected a saved classifiers.OneVsOneSVC"):
        OneVsOneSVC.load(tmp_path / "other.safetensors")
