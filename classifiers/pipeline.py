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

import contextlib
import inspect
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor
from tqdm.auto import tqdm

from classifiers.backbone import BACKBONES, Backbone, _device_and_dtype, load_backbone
from classifiers.preprocess import as_image_batch, augment, center_crop
from classifiers.quantize import Calibration, Calibrator, Int8Backbone, int8_unavailable
from classifiers.svm import OneVsOneSVC
from hbni_infra.checks import as_choice, as_float, as_int
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.threads import torch_threads
from hbni_infra.streams import numpy_generator

__all__ = ["FrameClassifier"]

_KIND = "classifiers.FrameClassifier"
PRECISIONS = ("auto", "int8", "float")


def _check_params(params: dict[str, Any]) -> None:
    """Refuse a bad set of constructor arguments with an error naming the argument."""
    if not isinstance(params["backbone"], str) or params["backbone"] not in BACKBONES:
        raise ValueError(f"backbone: expected one of {list(BACKBONES)}, got {params['backbone']!r}")
    path = params["weights_path"]
    if path is not None:
        if not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"weights_path: expected a path or None, got {type(path).__name__}")
        if not Path(path).is_file():
            raise FileNotFoundError(f"weights_path: no such weights file {str(path)!r}")
    elif params["backbone"] != "efficientnet_lite0":
        raise ValueError(f"weights_path: required for backbone={params['backbone']!r}")
    as_float("C", params["C"], 0.0, low_open=True)
    as_int("cv", params["cv"], 2)
    as_float("padding", params["padding"], 0.0)
    as_int("seed", params["seed"], 0)
    as_int("batch_size", params["batch_size"], 1)
    if params["threads"] is not None:
        as_int("threads", params["threads"], 1)
    if not isinstance(params["half"], bool):
        raise TypeError(f"half: expected a bool, got {params['half']!r}")
    if params["dtype"] is not None and not isinstance(params["dtype"], torch.dtype):
        raise TypeError(f"dtype: expected a torch.dtype or None, got {params['dtype']!r}")
    device, dtype = _device_and_dtype(params["device"], params["dtype"], params["half"])
    if not isinstance(params["precision"], str):
        raise TypeError(f"precision: expected one of {list(PRECISIONS)}, got {params['precision']!r}")
    as_choice("precision", params["precision"], PRECISIONS)
    if params["precision"] == "int8":
        reason = _int8_refusal(params["backbone"], device, dtype)
        if reason is not None:
            raise ValueError(f"precision: 'int8' {reason}")


def _int8_refusal(backbone: str, device: torch.device, dtype: torch.dtype) -> str | None:
    """Why a classifier with these settings cannot run its backbone in 8 bits (``None``: it can)."""
    if backbone != "efficientnet_lite0":
        return f"is written for efficientnet_lite0, not {backbone!r}"
    if dtype != torch.float32:
        return f"replaces float32, not dtype={dtype}"
    reason = int8_unavailable(device)
    return None if reason is None else f"cannot run here: {reason}"


def _same(value: Any, default: Any) -> bool:
    return value is default or (type(value) is type(default) and value == default)


class FrameClassifier:
    """Images in, class probabilities out: a scikit-learn classifier on uint8 BGR image batches.

    The scikit-learn estimator contract holds without importing scikit-learn (an optional package here):
    the constructor only checks and stores its arguments (:meth:`get_params` returns them as given),
    :meth:`set_params` checks what it sets, so :func:`sklearn.base.clone`, ``is_classifier`` and
    ``cross_val_score`` work; ``X`` is a batch of images (anything :func:`~classifiers.preprocess.as_image_batch`
    reads), not a feature matrix. Unlike scikit-learn's own estimators, bad arguments are refused at once,
    in ``__init__``, :meth:`set_params` and on assignment (``clf.padding = ...``), not at ``fit``. The backbone is
    loaded at first use (:attr:`backbone_`), shared through :func:`~classifiers.backbone.load_backbone`.

    Precision: on an x86-64 CPU the backbone runs in 8-bit integers by default (:mod:`classifiers.quantize`):
    ``fit`` calibrates it on its own training crops, whose float32 scores train the head. It classifies mission
    frames as accurately as float32 (within a point) in about 0.4 of its CPU time per frame (``docs/benchmarks.md``,
    ``docs/devices.md``). On CUDA, and on CPUs without the kernels (not x86-64, no AVX2), it runs in float.

    Args:
        backbone: backbone name (``"efficientnet_lite0"`` or ``"alexnet"``).
        weights_path: local backbone weights; ``None`` = the packaged EfficientNet-Lite0 weights.
        C: SVM penalty (> 0). cv: Platt cross-validation folds (an int >= 2). padding: crop padding fraction
            (finite, >= 0). seed: seed of the augmentation and of the Platt split (an int >= 0).
        batch_size: images per backbone call, an int >= 1 (4 keeps a CPU core's activations in its cache: a
            quarter faster than 8; outputs are the same for any batch size).
        threads: torch intra-op threads for feature extraction and prediction (an int >= 1; ``None``: torch's
            global setting). One thread is the default: on a small shared machine it is as fast as
            two when idle and many times faster when other processes compete for the cores.
        device: where the backbone runs (CPU by default); see :meth:`to`.
        dtype, half: float backbone precision, half only on CUDA (see :class:`~classifiers.backbone.Backbone`).
        precision: ``"auto"`` (8-bit integers where the CPU runs them, else float: see :attr:`precision_`),
            ``"int8"`` (refused where it cannot run) or ``"float"`` (``dtype``, float32 by default).

    Attributes (after ``fit`` or :meth:`load`):
        classes_: the sorted class labels (list; ``None`` before fitting).
        head_: the fitted :class:`~classifiers.svm.OneVsOneSVC`.
        mean_, scale_: ``(1000,)`` float64 feature standardisation.
        calibration_: the 8-bit activation grids (:class:`~classifiers.quantize.Calibration`), when
            :attr:`precision_` is ``"int8"``.

    Raises:
        TypeError, ValueError: an argument of the wrong type or out of range (the message names it).
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
        precision: str = "auto",
    ):
        params = {name: value for name, value in locals().items() if name in _PARAMS}
        _check_params(params)
        self.__dict__.update(params)

    def __getstate__(self) -> dict[str, Any]:
        """The state without the loaded networks (rebuilt at first use: the 8-bit one's packed weights cannot be
        copied), so pickle and ``copy.deepcopy`` work; files are :meth:`save`'s business."""
        return {k: v for k, v in self.__dict__.items() if k not in ("backbone_", "_int8_backbone")}

    def __setattr__(self, name: str, value: Any) -> None:
        """Assigning a constructor argument checks it as the constructor does (:meth:`set_params`)."""
        if name in _PARAMS:
            self.set_params(**{name: value})
        else:
            super().__setattr__(name, value)

    _estimator_type = "classifier"  # scikit-learn < 1.6 reads this; newer versions read __sklearn_tags__

    # ---- the scikit-learn estimator contract ----------------------------------------------------
    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor's arguments as stored (``deep`` is accepted for scikit-learn; there are no sub-estimators)."""
        return {name: getattr(self, name) for name in _PARAMS}

    def set_params(self, **params: Any) -> FrameClassifier:
        """Set constructor arguments, checked together as the constructor checks them; returns ``self``.

        A new backbone, weights path, placement or precision takes effect at the next use (the loaded backbone is
        dropped); the fitted head and calibration are kept until the next ``fit``.

        Raises:
            ValueError: an unknown name; TypeError, ValueError, FileNotFoundError as the constructor.
        """
        unknown = sorted(set(params) - set(_PARAMS))
        if unknown:
            raise ValueError(f"set_params: unknown parameters {unknown}, expected names among {list(_PARAMS)}")
        _check_params(self.get_params() | params)
        self.__dict__.update(params)
        placement = {"backbone", "weights_path", "device", "dtype", "half"}
        if set(params) & placement:
            self.__dict__.pop("backbone_", None)
        if set(params) & (placement | {"precision", "batch_size"}):
            self.__dict__.pop("_int8_backbone", None)
        return self

    def __repr__(self) -> str:
        """``FrameClassifier(...)`` with the arguments that differ from the defaults."""
        changed = [f"{k}={v!r}" for k, v in self.get_params().items() if not _same(v, _PARAMS[k])]
        return f"{type(self).__name__}({', '.join(changed)})"

    def __sklearn_tags__(self) -> Any:
        """scikit-learn's tags (scikit-learn >= 1.6; imported here, only scikit-learn calls this): a classifier
        whose input is a batch of images, not a 2-d feature array; fitted results depend on ``seed`` only."""
        from sklearn.utils import ClassifierTags, InputTags, Tags, TargetTags

        return Tags(
            estimator_type="classifier",
            target_tags=TargetTags(required=True),
            classifier_tags=ClassifierTags(),
            input_tags=InputTags(two_d_array=False, three_d_array=True),
        )

    def __sklearn_is_fitted__(self) -> bool:
        return "head_" in self.__dict__

    def score(self, X: Any, y: Sequence | np.ndarray | Tensor, sample_weight: Any = None) -> float:
        """Mean accuracy of :meth:`predict` on images ``X`` against labels ``y`` (weighted by ``sample_weight``)."""
        truth = np.asarray(y.tolist() if isinstance(y, Tensor) else y)
        hits = np.asarray(self.predict(X)) == truth
        return float(np.average(hits, weights=None if sample_weight is None else np.asarray(sample_weight)))

    # ---- backbone, precision and placement ------------------------------------------------------
    @property
    def backbone_(self) -> Backbone:
        """The float backbone network, loaded (shared, see :func:`~classifiers.backbone.load_backbone`) at first use."""
        if "backbone_" not in self.__dict__:
            loaded = load_backbone(self.backbone, self.weights_path)
            self.__dict__["backbone_"] = loaded.to(self.device, torch.float16 if self.half else self.dtype)
        return self.__dict__["backbone_"]

    @property
    def precision_(self) -> str:
        """The backbone's arithmetic under the current settings: ``"int8"`` (``precision="int8"``, or ``"auto"`` on a
        CPU that runs :mod:`classifiers.quantize`'s kernels with a float32 EfficientNet-Lite0) or ``"float"``."""
        if self.precision == "auto":
            device, dtype = _device_and_dtype(self.device, self.dtype, self.half)
            return "float" if _int8_refusal(self.backbone, device, dtype) else "int8"
        return self.precision

    @property
    def classes_(self) -> list | None:
        head = self.__dict__.get("head_")
        return None if head is None else head.classes_.tolist()

    def to(self, device: str | torch.device, dtype: torch.dtype | None = None) -> FrameClassifier:
        """Run the backbone on ``device`` in ``dtype`` (default float32) from now on; returns ``self``.

        Sets the ``device``, ``dtype`` and ``half`` parameters; the fitted head and standardisation stay on
        the CPU (outputs are CPU tensors on every device). ``precision="auto"`` runs float off the CPU.
        """
        self.set_params(device=device, dtype=dtype, half=False)
        return self

    def calibrate(self, images: Any, progress: bool = False, workers: int = 1) -> FrameClassifier:
        """Measure the 8-bit backbone's activation grids on the padded centre crops of ``images`` (``fit`` does this
        on its own training crops); returns ``self``. A classifier whose :attr:`precision_` is ``"float"`` refuses.
        """
        size = self.backbone_.input_size
        crops = [center_crop(im, size, self.padding) for im in as_image_batch(images)]
        self._calibrated_features(crops, progress, workers)
        return self

    def _calibrated_features(self, crops: list[np.ndarray], progress: bool, workers: int) -> Tensor:
        """Float backbone scores of ``crops``, measuring the activations on the way to set :attr:`calibration_`."""
        if self.precision_ != "int8":
            raise ValueError(
                f"precision: calibration is for the 8-bit backbone, this classifier runs {self.precision_}"
            )
        calibrator = Calibrator(self.backbone_)
        x = self._embed(crops, progress, workers, calibrator)
        self.calibration_ = calibrator.calibration()
        self.__dict__.pop("_int8_backbone", None)
        return x

    def _network(self) -> Backbone | Int8Backbone:
        """What embeds crops: the float :attr:`backbone_`, or its 8-bit twin built on :attr:`calibration_`."""
        if self.precision_ == "float":
            return self.backbone_
        if "_int8_backbone" not in self.__dict__:
            if "calibration_" not in self.__dict__:
                raise RuntimeError(
                    "FrameClassifier: the 8-bit backbone is not calibrated: call fit() on images, calibrate() or "
                    "load() first (or set precision='float')"
                )
            self.__dict__["_int8_backbone"] = Int8Backbone(self.backbone_, self.calibration_, self.batch_size)
        return self.__dict__["_int8_backbone"]

    # ---- features -------------------------------------------------------------------------------
    def _embed(self, crops: list[np.ndarray], progress: bool, workers: int = 1, network: Any = None) -> Tensor:
        """Scores of ``crops`` by ``network`` (default: the backbone in :attr:`precision_`), a chunk of ``batch_size``
        at a time, ``workers`` chunks side by side (each on one torch thread: the same values as one after another)."""
        workers = as_int("workers", workers, minimum=1)
        if workers > 1 and self.threads not in (None, 1):
            raise ValueError(f"workers: {workers} threads need a classifier on one torch thread, it has {self.threads}")
        chunks = [crops[i : i + self.batch_size] for i in range(0, len(crops), self.batch_size)]
        network = self._network() if network is None else network

        def embed(chunk: list[np.ndarray]) -> Tensor:
            return network.scores(chunk, self.batch_size, threads=None)

        bar = tqdm(total=len(crops), desc="backbone", unit="img", disable=not progress, leave=False)
        pool = ThreadPoolExecutor(workers) if workers > 1 else contextlib.nullcontext()  # one: no thread to start
        with torch_threads(1 if workers > 1 else self.threads), pool:
            out = []
            for chunk, scores in zip(chunks, (pool.map if workers > 1 else map)(embed, chunks)):
                out.append(scores)
                bar.update(len(chunk))
        bar.close()
        return torch.cat(out)

    def features(self, images: Any, progress: bool = False) -> Tensor:
        """Backbone scores ``(B, 1000)`` float32 of the padded centre crops of ``images``."""
        size = self.backbone_.input_size
        with torch_threads(self.threads):  # one thread setting for cropping and embedding (changing it costs)
            return self._embed([center_crop(im, size, self.padding) for im in as_image_batch(images)], progress)

    def augmented_features(self, images: Any, copies: int, progress: bool = False, workers: int = 1) -> Tensor:
        """Features ``(B * (1 + copies), 1000)``: each image's centre crop, then ``copies`` random crops/mirrors.

        Rows are grouped per image: ``[crop_0, aug_0_1, .., aug_0_copies, crop_1, ...]``. Seeded by ``seed``.
        ``workers`` threads embed them side by side (the same values; the classifier must run on one torch thread).
        """
        return self._embed(self._training_crops(as_image_batch(images), copies), progress, workers)

    def _training_crops(self, images: list[np.ndarray], copies: int) -> list[np.ndarray]:
        """Each image's centre crop, then ``copies`` random crops/mirrors of it (seeded by ``seed``)."""
        if copies < 0:
            raise ValueError(f"copies: expected >= 0, got {copies}")
        rng = numpy_generator(self.seed)
        size = self.backbone_.input_size
        crops = []
        for im in images:
            crops.append(center_crop(im, size, self.padding))
            crops += [augment(im, rng, size, self.padding) for _ in range(copies)]
        return crops

    # ---- training and prediction ----------------------------------------------------------------
    def _check_fitted(self, what: str = "call fit() or load() first") -> None:
        if not self.__sklearn_is_fitted__():
            raise RuntimeError(f"FrameClassifier: {what}")

    def fit_features(self, X: Tensor, y: Sequence | np.ndarray | Tensor) -> FrameClassifier:
        """Fit the standardisation and the SVM head on backbone features ``X (N, 1000)`` and labels ``y``."""
        if not isinstance(X, Tensor) or X.ndim != 2 or X.shape[1] != self.backbone_.num_features:
            raise ValueError(f"X: expected a (N, {self.backbone_.num_features}) tensor, got {getattr(X, 'shape', X)}")
        x = X.double()
        mean, scale = x.mean(0), x.std(0).clamp_min(1e-6)
        self.head_ = OneVsOneSVC(C=self.C, cv=self.cv, seed=self.seed).fit((x - mean) / scale, y)
        self.mean_, self.scale_ = mean, scale
        return self

    def fit(
        self,
        images: Any,
        labels: Sequence | np.ndarray | Tensor,
        augment: int = 0,
        progress: bool = False,
        workers: int = 1,
    ) -> FrameClassifier:
        """Train on ``images`` with ``labels`` (one per image); ``augment`` extra random crops/mirrors each, embedded by
        ``workers`` threads side by side (the same fit).

        With an 8-bit backbone (:attr:`precision_`), the head still learns from the float network's scores of these
        crops, which also calibrate the 8-bit grids (:meth:`calibrate`): plain, bright training snapshots quantize
        with about three times the relative error of camera frames (large flat regions round alike), and a head
        trained on their 8-bit scores classified mission frames 24 points worse (``docs/benchmarks.md``)."""
        batch = as_image_batch(images)
        if isinstance(labels, (str, bytes)) or not hasattr(labels, "__len__"):
            raise TypeError(
                f"labels: expected one class name per image (a list, array or tensor), got {type(labels).__name__}"
            )
        labels = list(labels.tolist() if isinstance(labels, (Tensor, np.ndarray)) else labels)
        if len(labels) != len(batch):
            raise ValueError(f"labels: expected {len(batch)} labels, got {len(labels)}")
        crops = self._training_crops(batch, augment)
        if self.precision_ == "int8":
            x = self._calibrated_features(crops, progress, workers)
        else:
            x = self._embed(crops, progress, workers)
        return self.fit_features(x, [lab for lab in labels for _ in range(1 + augment)])

    def _head_proba(self, X: Tensor) -> Tensor:
        """Class probabilities ``(B, M)`` float64 from backbone features ``(B, 1000)``."""
        self._check_fitted()
        with torch_threads(self.threads):
            return self.head_.proba((X.double() - self.mean_) / self.scale_)

    def proba_from_features(self, X: Tensor) -> Tensor:
        """Class probabilities ``(B, M)`` float32 from backbone features ``(B, 1000)`` (a CPU torch tensor)."""
        return self._head_proba(X).float()

    def proba(self, images: Any) -> Tensor:
        """Class probabilities ``(B, M)``, columns in ``classes_`` order (rows sum to 1), as a float32 CPU torch
        tensor on every input and device: the classifier outputs the noise models (``hbni_pyro``) read."""
        return self._proba(images).float()

    def predict_proba(self, images: Any) -> np.ndarray:
        """Class probabilities ``(B, M)`` as scikit-learn returns them: a float64 array, columns in ``classes_`` order,
        rows summing to 1 within float64 rounding (:meth:`proba` is the torch twin)."""
        return self._proba(images).numpy()

    def _proba(self, images: Any) -> Tensor:
        self._check_fitted()
        with torch_threads(self.threads):
            return self._head_proba(self.features(images))

    def predict(self, images: Any) -> np.ndarray:
        """The most probable class label per image ``(B,)`` (an array, labels as in ``classes_``)."""
        return np.asarray(self.classes_)[self.predict_proba(images).argmax(-1)]

    # ---- storage --------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the fitted classifier to one safetensors file (atomic; backbone weights referenced, not copied).

        The file records the backbone's precision (:attr:`precision_`) and, for ``"int8"``, the activation grids
        (:attr:`calibration_`): :meth:`load` rebuilds the same integer network from the backbone weights.
        """
        self._check_fitted("nothing to save, call fit() first")
        tensors, head_meta = self.head_.state()
        tensors = {f"head.{k}": v for k, v in tensors.items()} | {"mean": self.mean_, "scale": self.scale_}
        if self.precision_ == "int8" and "calibration_" in self.__dict__:
            grids = self.calibration_
            tensors |= {"calibration.scales": grids.scales, "calibration.zero_points": grids.zero_points}
        meta = {
            "precision": self.precision_,
            "head": head_meta,
            "backbone": self.backbone,
            "weights_path": None if self.weights_path is None else str(self.weights_path),
            "padding": float(self.padding),
            "seed": int(self.seed),
            "batch_size": int(self.batch_size),
            "threads": None if self.threads is None else int(self.threads),
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

        The recorded precision is kept (an 8-bit classifier loads on a CPU that runs it, with its calibration: the
        same outputs, bit for bit, as when it was saved on this machine); a file without one predates 8-bit
        backbones and loads as float.

        Raises:
            FileNotFoundError: ``path`` or the backbone weights do not exist.
            ValueError: corrupt or foreign file, or a setting the constructor refuses (an 8-bit classifier on a
                device or CPU without 8-bit kernels).
        """
        _device_and_dtype(device, dtype, False)
        tensors, meta = load_tensors(path, _KIND)
        try:
            head_meta = meta["head"]
            params = {name: meta[name] for name in ("backbone", "weights_path", "padding", "seed", "batch_size")}
            params |= {"C": head_meta["C"], "cv": head_meta["cv"], "threads": meta["threads"]}
            params["precision"] = meta.get("precision", "float")
            mean, scale = tensors["mean"].double(), tensors["scale"].double()
        except (KeyError, TypeError) as exc:
            raise ValueError(f"path: {str(path)!r} is missing entry {exc}") from exc
        params["weights_path"] = weights_path or params["weights_path"]
        try:
            model = cls(**params, device=device, dtype=dtype)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid setting: {exc}") from exc
        if "calibration.scales" in tensors or "calibration.zero_points" in tensors:
            model.calibration_ = _read_calibration(tensors, model.backbone_, path)
        model.mean_, model.scale_ = mean, scale
        try:
            model.head_ = OneVsOneSVC.from_state(
                {k[5:]: v for k, v in tensors.items() if k.startswith("head.")}, head_meta
            )
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None
        if model.mean_.shape != (model.backbone_.num_features,) or model.head_.coef_.shape[1] != model.mean_.shape[0]:
            raise ValueError(f"path: {str(path)!r} has inconsistent feature sizes")
        if not bool(torch.isfinite(model.mean_).all()) or not bool((model.scale_ > 0).all()):
            raise ValueError(
                f"path: {str(path)!r} holds an invalid {_KIND} (mean and scale: expected finite, scale > 0)"
            )
        return model


def _read_calibration(tensors: dict[str, Tensor], backbone: Backbone, path: str | os.PathLike) -> Calibration:
    """The 8-bit activation grids saved in a classifier file, checked against ``backbone``."""
    try:
        grids = Calibration(tensors["calibration.scales"], tensors["calibration.zero_points"])
        return grids.check(backbone.fused_network)
    except KeyError as exc:
        raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} (calibration: missing {exc})") from None
    except ValueError as exc:
        raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None


_PARAMS = {
    name: p.default for name, p in inspect.signature(FrameClassifier.__init__).parameters.items() if name != "self"
}
"""Every constructor argument and its default, read from the signature (as scikit-learn reads it)."""
