"""The frame classifier: uint8 BGR images -> ``(B, M)`` class probabilities.

Pipeline: the paper's padded centre crop (OpenCV) -> pretrained backbone (1000 ImageNet
scores as the feature) -> per-feature standardisation -> one-vs-one linear SVMs with Platt
scaling and pairwise coupling (:class:`classifiers.svm.OneVsOneSVC`).

A fitted classifier is saved to ONE safetensors file (head, standardisation, settings;
no pickle). The backbone weights are not copied into it: they are read again from the
installed package (or the recorded ``weights_path``) when the file is loaded.

Devices: the backbone (the only heavy part) runs batched on ``device`` (CPU by default), optionally
in half precision on CUDA; its features come back to the CPU once per batch, where the float64
standardisation and the small SVM head run, so probabilities are float32 CPU tensors on every device.
A saved file holds no device: :meth:`FrameClassifier.load` places it on any ``device``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor
from tqdm.auto import tqdm

from classifiers.backbone import Backbone, load_backbone
from classifiers.preprocess import as_image_batch, augment, center_crop, normalize
from classifiers.svm import OneVsOneSVC
from hbni_infra.checks import as_float, as_int
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.threads import torch_threads

__all__ = ["FrameClassifier"]

_KIND = "classifiers.FrameClassifier"


class FrameClassifier:
    """Images in, class probabilities out.

    Args:
        backbone: backbone name (``"efficientnet_lite0"`` or ``"alexnet"``).
        weights_path: local backbone weights; ``None`` = the packaged EfficientNet-Lite0 weights.
        C: SVM penalty. cv: Platt cross-validation folds. padding: crop padding fraction.
        seed: seed of the augmentation and of the Platt split.
        batch_size: images per backbone call (4 keeps a CPU core's activations in its cache: a quarter faster
            than 8; outputs are the same for any batch size).
        threads: torch intra-op threads for feature extraction and prediction (``None``: torch's
            global setting). One thread is the default: on a small shared machine it is as fast as
            two when idle and many times faster when other processes compete for the cores.
        device: where the backbone runs (CPU by default); see :meth:`to`.
        dtype, half: backbone precision, half only on CUDA (see :class:`~classifiers.backbone.Backbone`).

    Raises:
        FileNotFoundError: ``weights_path`` does not exist.
    """

    def __init__(
        self,
        backbone: str = "efficientnet_lite0",
        weights_path: str | os.PathLike | None = None,
        C: float = 1.0,
        cv: int = 5,
        padding: float = 0.1,
        seed: int = 0,
        batch_size: int = 4,
        threads: int | None = 1,
        device: str | torch.device = "cpu",
        dtype: torch.dtype | None = None,
        half: bool = False,
    ):
        if padding < 0:
            raise ValueError(f"padding: expected >= 0, got {padding}")
        if batch_size < 1:
            raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
        self.backbone: Backbone = load_backbone(backbone, weights_path).to(device, torch.float16 if half else dtype)
        self.weights_path = None if weights_path is None else str(weights_path)
        self.padding = float(padding)
        self.seed = int(seed)
        self.batch_size = int(batch_size)
        if threads is not None and threads < 1:
            raise ValueError(f"threads: expected >= 1 or None, got {threads}")
        self.threads = threads
        self.head = OneVsOneSVC(C=C, cv=cv, seed=seed)
        self.mean_: Tensor | None = None
        self.scale_: Tensor | None = None

    @property
    def classes_(self) -> list | None:
        return self.head.classes_

    @property
    def device(self) -> torch.device:
        """Where the backbone runs."""
        return self.backbone.device

    def to(self, device: str | torch.device, dtype: torch.dtype | None = None) -> FrameClassifier:
        """Run the backbone on ``device`` in ``dtype`` (default float32) from now on; returns ``self``.

        The fitted head and standardisation stay on the CPU (outputs are CPU tensors on every device).
        """
        self.backbone = self.backbone.to(device, dtype)
        return self

    # ---- features -------------------------------------------------------------------------------
    def _embed(self, crops: list[np.ndarray], progress: bool) -> Tensor:
        out = []
        bar = tqdm(total=len(crops), desc="backbone", unit="img", disable=not progress, leave=False)
        with torch_threads(self.threads):
            for i in range(0, len(crops), self.batch_size):
                chunk = crops[i : i + self.batch_size]
                x = normalize(chunk, self.backbone.mean, self.backbone.std)
                out.append(self.backbone(x, self.batch_size, threads=None))
                bar.update(len(chunk))
        bar.close()
        return torch.cat(out)

    def features(self, images: Any, progress: bool = False) -> Tensor:
        """Backbone scores ``(B, 1000)`` float32 of the padded centre crops of ``images``."""
        size = self.backbone.input_size
        return self._embed([center_crop(im, size, self.padding) for im in as_image_batch(images)], progress)

    def augmented_features(self, images: Any, copies: int, progress: bool = False) -> Tensor:
        """Features ``(B * (1 + copies), 1000)``: each image's centre crop, then ``copies`` random crops/mirrors.

        Rows are grouped per image: ``[crop_0, aug_0_1, .., aug_0_copies, crop_1, ...]``. Seeded by ``seed``.
        """
        if copies < 0:
            raise ValueError(f"copies: expected >= 0, got {copies}")
        rng = np.random.default_rng(self.seed)
        size = self.backbone.input_size
        crops = []
        for im in as_image_batch(images):
            crops.append(center_crop(im, size, self.padding))
            crops += [augment(im, rng, size, self.padding) for _ in range(copies)]
        return self._embed(crops, progress)

    # ---- training and prediction ----------------------------------------------------------------
    def fit_features(self, X: Tensor, y: Sequence | np.ndarray | Tensor) -> FrameClassifier:
        """Fit the standardisation and the SVM head on backbone features ``X (N, 1000)`` and labels ``y``."""
        if not isinstance(X, Tensor) or X.ndim != 2 or X.shape[1] != self.backbone.num_features:
            raise ValueError(f"X: expected a (N, {self.backbone.num_features}) tensor, got {getattr(X, 'shape', X)}")
        x = X.double()
        self.mean_ = x.mean(0)
        self.scale_ = x.std(0).clamp_min(1e-6)
        self.head.fit((x - self.mean_) / self.scale_, y)
        return self

    def fit(
        self, images: Any, labels: Sequence | np.ndarray | Tensor, augment: int = 0, progress: bool = False
    ) -> FrameClassifier:
        """Train on ``images`` with ``labels`` (one per image); ``augment`` extra random crops/mirrors each."""
        batch = as_image_batch(images)
        if isinstance(labels, (str, bytes)) or not hasattr(labels, "__len__"):
            raise TypeError(
                f"labels: expected one class name per image (a list, array or tensor), got {type(labels).__name__}"
            )
        labels = list(labels.tolist() if isinstance(labels, (Tensor, np.ndarray)) else labels)
        if len(labels) != len(batch):
            raise ValueError(f"labels: expected {len(batch)} labels, got {len(labels)}")
        x = self.augmented_features(batch, augment, progress)
        return self.fit_features(x, [lab for lab in labels for _ in range(1 + augment)])

    def proba_from_features(self, X: Tensor) -> Tensor:
        """Class probabilities ``(B, M)`` float32 from backbone features ``(B, 1000)``."""
        if self.mean_ is None:
            raise RuntimeError("FrameClassifier: call fit() or load() first")
        with torch_threads(self.threads):
            return self.head.predict_proba((X.double() - self.mean_) / self.scale_).float()

    def predict_proba(self, images: Any) -> Tensor:
        """Class probabilities ``(B, M)`` float32, columns in ``classes_`` order (rows sum to 1)."""
        return self.proba_from_features(self.features(images))

    def predict(self, images: Any) -> list:
        """The most probable class label per image."""
        return [self.classes_[k] for k in self.predict_proba(images).argmax(-1).tolist()]

    # ---- storage --------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the fitted classifier to one safetensors file (atomic; backbone weights referenced, not copied)."""
        if self.mean_ is None:
            raise RuntimeError("FrameClassifier: nothing to save, call fit() first")
        tensors, head_meta = self.head.state()
        tensors = {f"head.{k}": v for k, v in tensors.items()} | {"mean": self.mean_, "scale": self.scale_}
        meta = {
            "head": head_meta,
            "backbone": self.backbone.name,
            "weights_path": self.weights_path,
            "padding": self.padding,
            "seed": self.seed,
            "batch_size": self.batch_size,
            "threads": self.threads,
        }
        return save_tensors(path, _KIND, tensors, meta)

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        weights_path: str | os.PathLike | None = None,
        device: str | torch.device = "cpu",
        dtype: torch.dtype | None = None,
    ) -> FrameClassifier:
        """Read a classifier written by :meth:`save` (on any device); ``weights_path`` overrides the recorded
        backbone weights; the backbone runs on ``device`` in ``dtype`` (tensors are read onto the CPU first).

        Raises:
            FileNotFoundError: ``path`` or the backbone weights do not exist.
            ValueError: corrupt or foreign file.
        """
        tensors, meta = load_tensors(path, _KIND)
        try:
            head_meta = meta["head"]
            settings = _settings(meta, weights_path)
            model = cls(**settings, C=1.0, device=device, dtype=dtype)
            model.head = OneVsOneSVC.from_state(
                {k[5:]: v for k, v in tensors.items() if k.startswith("head.")}, head_meta
            )
            model.mean_, model.scale_ = tensors["mean"].double(), tensors["scale"].double()
        except KeyError as exc:
            raise ValueError(f"path: {str(path)!r} is missing entry {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None
        if model.mean_.shape != (model.backbone.num_features,) or model.head.coef_.shape[1] != model.mean_.shape[0]:
            raise ValueError(f"path: {str(path)!r} has inconsistent feature sizes")
        if not bool(torch.isfinite(model.mean_).all()) or not bool((model.scale_ > 0).all()):
            raise ValueError(
                f"path: {str(path)!r} holds an invalid {_KIND} (mean and scale: expected finite, scale > 0)"
            )
        return model


def _settings(meta: dict[str, Any], weights_path: str | os.PathLike | None) -> dict[str, Any]:
    """The constructor settings a saved classifier records, checked as :class:`FrameClassifier` checks them."""
    backbone, recorded = meta["backbone"], meta["weights_path"]
    if not isinstance(backbone, str):
        raise TypeError(f"backbone: expected a name, got {backbone!r}")
    if recorded is not None and not isinstance(recorded, str):
        raise TypeError(f"weights_path: expected a path or null, got {recorded!r}")
    threads = meta["threads"]
    return {
        "backbone": backbone,
        "weights_path": weights_path or recorded,
        "padding": as_float("padding", meta["padding"], 0.0),
        "seed": as_int("seed", meta["seed"]),
        "batch_size": as_int("batch_size", meta["batch_size"], minimum=1),
        "threads": None if threads is None else as_int("threads", threads, minimum=1),
    }
