"""Per-frame calibration (temperature scaling, Dirichlet calibration in matrix form) and the calibrated peer."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar
from sklearn.linear_model import LogisticRegression

from hbni_pyro import (
    FrameCalibration,
    StaticStateBayesFilter,
    fit_frame_calibration,
    fit_temper,
    make_filter,
    sample_outputs,
)

THETA = torch.tensor([1.0, 3.0, 6.0], dtype=torch.float64)


def labelled_frames(num: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    labels = torch.arange(3).repeat(num // 3)
    return sample_outputs(THETA, labels, g), labels


def test_matrix_form_is_multinomial_logistic_regression_on_log_probabilities():
    """The matrix form equals scikit-learn's multinomial LogisticRegression on log o with the same ridge
    (``C = 1 / (l2 N)``): weights, and the calibrated probabilities (intercepts agree up to a shared shift)."""
    obs, labels = labelled_frames(900)
    l2 = 1e-3
    cal = fit_frame_calibration(obs, labels, "matrix", l2=l2)
    ref = LogisticRegression(C=1 / (l2 * len(labels)), tol=1e-12, max_iter=10_000)
    ref.fit(obs.log().numpy(), labels.numpy())
    np.testing.assert_allclose(cal.weight.numpy(), ref.coef_, atol=1e-5)
    np.testing.assert_allclose(cal(obs).numpy(), ref.predict_proba(obs.log().numpy()), atol=1e-6)
    assert cal.info["loss"] < cal.info["raw_loss"]


def test_temperature_minimises_the_log_loss():
    """Temperature scaling's T is the minimiser of the mean log loss of softmax(log o / T) (a 1-D search as the
    reference); the map is I / T with no bias."""
    obs, labels = labelled_frames(600, seed=1)
    x, y = obs.log(), labels

    def loss(log_t: float) -> float:
        return float(torch.nn.functional.cross_entropy(x / np.exp(log_t), y))

    best = minimize_scalar(loss, bounds=(-5, 5), method="bounded", options={"xatol": 1e-10})
    cal = fit_frame_calibration(obs, labels, "temperature")
    assert cal.info["temperature"] == pytest.approx(np.exp(best.x), rel=1e-5)
    torch.testing.assert_close(cal.weight, torch.eye(3, dtype=torch.float64) / cal.info["temperature"])
    assert torch.equal(cal.bias, torch.zeros(3, dtype=torch.float64))


def test_calibrated_outputs_need_no_calibration():
    """Outputs that are the Bayes posterior of their own labels (a label drawn from each output) are calibrated:
    the fitted temperature is 1 within its Monte Carlo error (a few per cent with 6000 frames)."""
    g = torch.Generator().manual_seed(2)
    obs = torch.distributions.Dirichlet(torch.full((3,), 0.7, dtype=torch.float64)).sample((6000,))
    obs = obs.clamp_min(1e-4) / obs.clamp_min(1e-4).sum(-1, keepdim=True)
    labels = torch.multinomial(obs, 1, generator=g)[:, 0]
    cal = fit_frame_calibration(obs, labels, "temperature")
    assert cal.info["temperature"] == pytest.approx(1.0, abs=0.08)


def test_fit_is_deterministic_and_keeps_batch_shapes():
    obs, labels = labelled_frames(300)
    a = fit_frame_calibration(obs.reshape(10, 10, 3, 3), labels.reshape(10, 10, 3), "matrix", max_iter=50)
    b = fit_frame_calibration(obs, labels, "matrix", max_iter=50)
    assert torch.equal(a.weight, b.weight) and torch.equal(a.bias, b.bias)
    assert a(obs.reshape(10, 30, 3)).shape == (10, 30, 3)


def test_save_load_round_trip(tmp_path):
    obs, labels = labelled_frames(300)
    cal = fit_frame_calibration(obs, labels, "temperature", class_names=["a", "b", "c"])
    back = FrameCalibration.load(cal.save(tmp_path / "cal.safetensors"))
    assert torch.equal(back.weight, cal.weight) and torch.equal(back.bias, cal.bias)
    assert (back.kind, back.class_names, back.info) == (cal.kind, cal.class_names, cal.info)
    (tmp_path / "foreign.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError):
        FrameCalibration.load(tmp_path / "foreign.safetensors")
    with pytest.raises(FileNotFoundError):
        FrameCalibration.load(tmp_path / "missing.safetensors")


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"kind": "platt"}, ValueError, "kind: expected one of"),
        ({"labels": torch.tensor([0, 1])}, ValueError, "labels"),
        ({"labels": torch.tensor([0, -1, 2, 1, 0, 2])}, ValueError, "labels: expected every frame's class"),
        ({"labels": torch.tensor([0, 1, 3, 1, 0, 2])}, ValueError, "labels"),
        ({"l2": -1.0}, ValueError, "l2"),
        ({"max_iter": 0}, ValueError, "max_iter"),
        ({"outputs": torch.tensor([[0.5, 0.6, 0.1]] * 6)}, ValueError, "outputs"),
    ],
)
def test_fit_errors(kwargs, error, message):
    obs, labels = labelled_frames(6)
    args = {"outputs": obs, "labels": labels, **kwargs}
    with pytest.raises(error, match=message):
        fit_frame_calibration(**args)


def test_map_errors():
    with pytest.raises(ValueError, match="weight"):
        FrameCalibration(torch.ones(2, 3), torch.zeros(2))
    with pytest.raises(ValueError, match="bias"):
        FrameCalibration(torch.eye(3), torch.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        FrameCalibration(torch.eye(3) * float("nan"), torch.zeros(3))
    with pytest.raises(ValueError, match="kind"):
        FrameCalibration(torch.eye(3), torch.zeros(3), kind="vector")
    with pytest.raises(ValueError, match="obs"):
        FrameCalibration(torch.eye(3), torch.zeros(3))(torch.tensor([0.5, 0.5]))


def test_calibrated_ssbf_by_hand():
    """The peer's posterior is ``p_m * prod_i (q_i,m / p_m)^tau`` normalised, q the calibrated frames; streaming
    and batched agree; the identity map at temper 1 is the plain SSBF."""
    obs, labels = labelled_frames(300)
    cal = fit_frame_calibration(obs, labels, "matrix")
    prior = torch.tensor([0.2, 0.3, 0.5], dtype=torch.float64)
    f = make_filter("calibrated", calibration=cal, temper=0.4, class_prior=prior)
    streams = obs[:40].reshape(4, 10, 3)
    q = cal(streams)
    log = prior.log() + 0.4 * (q.log() - prior.log()).cumsum(1)
    torch.testing.assert_close(f.run(streams), torch.softmax(log, -1))
    for n in range(10):
        streamed = f.update(streams[1, n])
    torch.testing.assert_close(streamed, f.run(streams)[1, -1], rtol=0, atol=1e-14)
    identity = FrameCalibration(torch.eye(3), torch.zeros(3))
    torch.testing.assert_close(
        make_filter("calibrated", calibration=identity).run(streams), StaticStateBayesFilter(3).run(streams)
    )
    assert f.tempered(1.0).temper == 1.0 and f.tempered(1.0).calibration is f.calibration


def test_fit_temper_weighs_the_peers_correlated_frames():
    """Frames repeated k times carry the evidence of one: the peer's fitted evidence weight falls with k, to at
    most about 2/k of the weight on distinct frames (the block's first frame is undercounted inside a block)."""
    obs, labels = labelled_frames(900, seed=4)
    peer = make_filter("calibrated", calibration=fit_frame_calibration(obs, labels, "matrix"))
    g = torch.Generator().manual_seed(5)
    truth = torch.randint(0, 3, (300,), generator=g)
    fitted = []
    for k in (1, 2, 4):
        frames = sample_outputs(THETA, truth.view(-1, 1).expand(-1, 8), g).repeat_interleave(k, dim=1)
        fitted.append(fit_temper(peer, frames, truth).temper)
    assert fitted == sorted(fitted, reverse=True) and len(set(fitted)) == 3
    assert fitted[2] <= 2 * fitted[0] / 4 + 0.05


def test_make_filter_calibrated_errors():
    with pytest.raises(ValueError, match="calibration: the 'calibrated' filter needs"):
        make_filter("calibrated", num_classes=3)
    with pytest.raises(ValueError, match="calibration: expected a map of 4 classes"):
        make_filter("calibrated", num_classes=4, calibration=FrameCalibration(torch.eye(3), torch.zeros(3)))
    with pytest.raises(TypeError, match="calibration: expected a FrameCalibration"):
        StaticStateBayesFilter(3, calibration="matrix")
    with pytest.raises(ValueError, match="temper"):
        make_filter("calibrated", calibration=FrameCalibration(torch.eye(3), torch.zeros(3)), temper=0.0)
