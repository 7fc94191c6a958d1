"""FrameClassifier: images in, probabilities out; fit, save/load, determinism and input errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from classifiers import FrameClassifier
from classifiers.data import render_images

VEHICLES = ("irobot", "quadrotor", "racecar")  # the classes of the paper's hardware study


@pytest.fixture(scope="module")
def frames():
    return np.concatenate([render_images(name, 2, "training", seed=9) for name in VEHICLES])  # (6, 240, 320, 3)


def test_proba_forms(fitted_classifier, frames):
    p = fitted_classifier.proba(frames)
    assert isinstance(p, torch.Tensor) and p.shape == (6, 3) and p.dtype == torch.float32
    assert torch.allclose(p.sum(-1), torch.ones(6), atol=1e-5)
    assert torch.allclose(fitted_classifier.proba(list(frames)), p)
    assert torch.allclose(fitted_classifier.proba(torch.from_numpy(frames)), p)
    assert torch.allclose(fitted_classifier.proba(frames[0]), p[:1])
    assert fitted_classifier.classes_ == sorted(VEHICLES)
    # scikit-learn's door: float64 arrays whose rows sum to one within float64 rounding, the same values
    q = fitted_classifier.predict_proba(frames)
    assert isinstance(q, np.ndarray) and q.dtype == np.float64 and q.shape == (6, 3)
    np.testing.assert_allclose(q.sum(1), 1.0, rtol=0, atol=4 * np.finfo(np.float64).eps)
    np.testing.assert_allclose(q, p.numpy(), rtol=0, atol=1e-7)
    labels = fitted_classifier.predict(frames)
    assert isinstance(labels, np.ndarray) and labels.tolist() == [fitted_classifier.classes_[k] for k in q.argmax(1)]


def test_fit_on_images_is_seeded(frames):
    labels = [VEHICLES[k // 2] for k in range(6)]
    images = np.concatenate([frames, frames[:, :, ::-1]])  # 4 images per class, cv=2
    a = FrameClassifier(cv=2, seed=1).fit(images, labels * 2, augment=1)
    b = FrameClassifier(cv=2, seed=1).fit(images, labels * 2, augment=1, workers=2)  # chunks embedded side by side
    assert torch.equal(a.proba(frames), b.proba(frames))  # the 8-bit grids too: calibrated in the same pass
    if a.precision_ == "int8":
        assert torch.equal(a.calibration_.scales, b.calibration_.scales)
    assert torch.equal(a.augmented_features(frames, 1), b.augmented_features(frames, 1, workers=3))
    with pytest.raises(ValueError, match="workers: 2 threads need a classifier on one torch thread, it has 2"):
        FrameClassifier(threads=2).fit(images, labels * 2, workers=2)
    with pytest.raises(ValueError, match="workers: expected an int >= 1"):
        a.augmented_features(frames, 1, workers=0)
    feats = a.augmented_features(frames[:2], copies=2)
    assert feats.shape == (6, 1000)
    assert torch.allclose(feats[0], a.features(frames[:1])[0], atol=1e-4)  # row 0 of each group is the centre crop


def test_save_load_round_trip(tmp_path, fitted_classifier, frames):
    path = fitted_classifier.save(tmp_path / "clf.safetensors")
    assert path.is_file() and not list(tmp_path.glob(".*tmp"))
    loaded = FrameClassifier.load(path)
    assert loaded.classes_ == fitted_classifier.classes_
    assert torch.equal(loaded.proba(frames), fitted_classifier.proba(frames))


def test_error_paths(tmp_path, fitted_classifier, frames):
    with pytest.raises(TypeError, match="uint8"):
        fitted_classifier.proba(frames.astype(np.float32))
    with pytest.raises(ValueError, match="3 BGR channels"):
        fitted_classifier.predict_proba(np.zeros((2, 32, 32, 4), np.uint8))
    with pytest.raises(ValueError, match="3 BGR channels"):
        fitted_classifier.predict_proba([np.zeros((32, 32, 1), np.uint8)])
    with pytest.raises(ValueError, match="empty batch"):
        fitted_classifier.predict_proba([])
    with pytest.raises(FileNotFoundError, match="weights_path"):
        FrameClassifier(weights_path=tmp_path / "missing.pth")
    with pytest.raises(RuntimeError, match="fit"):
        FrameClassifier().proba(frames)
    with pytest.raises(RuntimeError, match="fit"):
        FrameClassifier().save(tmp_path / "x.safetensors")
    with pytest.raises(ValueError, match="labels"):
        FrameClassifier().fit(frames, ["irobot"])
    with pytest.raises(ValueError, match="X"):
        FrameClassifier().fit_features(torch.zeros(4, 10), [0, 0, 1, 1])
    with pytest.raises(ValueError, match="padding"):
        FrameClassifier(padding=-1)
    with pytest.raises(ValueError, match="threads"):
        FrameClassifier(threads=0)
    with pytest.raises(ValueError, match="copies"):
        fitted_classifier.augmented_features(frames, -1)
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"{not safetensors}")
    with pytest.raises(ValueError, match="is not a readable model file"):
        FrameClassifier.load(corrupt)
    head_file = fitted_classifier.head_.save(tmp_path / "head.safetensors")
    with pytest.raises(ValueError, match="FrameClassifier"):
        FrameClassifier.load(head_file)
    with pytest.raises(FileNotFoundError):
        FrameClassifier.load(tmp_path / "missing.safetensors")
    saved = fitted_classifier.save(tmp_path / "clf.safetensors")
    with pytest.raises(FileNotFoundError, match="weights_path"):
        FrameClassifier.load(saved, weights_path=tmp_path / "missing.pth")
