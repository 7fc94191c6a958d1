"""Images -> probability vectors: CNN backbone features and a Platt-scaled one-vs-one SVM head.

Never imports ``hbni_pyro``: the two packages meet on a plain ``(N, M)`` probability tensor.

See ``docs/architecture.md`` for where this sits between the camera and the noise model.
"""

try:
    import cv2  # noqa: F401
except ImportError as exc:  # OpenCV is the user's choice (pyproject.toml's `opencv` extra)
    raise ImportError(
        "classifiers needs OpenCV: install the machine's own build (opencv-python, a ROS build) or "
        "`pip install hbni-pyro[opencv]` (opencv-python-headless)"
    ) from exc

from hbni_infra.version import __version__

from classifiers.backbone import Backbone, EfficientNetLite0, default_weights_path, load_backbone
from classifiers.coupling import pairwise_coupling
from classifiers.pipeline import FrameClassifier
from classifiers.platt import fit_platt, platt_predict
from classifiers.preprocess import augment, center_crop, crop_box, normalize
from classifiers.classify import class_columns, classify_frames
from classifiers.svm import OneVsOneSVC

__all__ = [
    "__version__",
    "Backbone",
    "EfficientNetLite0",
    "FrameClassifier",
    "OneVsOneSVC",
    "augment",
    "center_crop",
    "class_columns",
    "classify_frames",
    "crop_box",
    "default_weights_path",
    "fit_platt",
    "load_backbone",
    "normalize",
    "pairwise_coupling",
    "platt_predict",
]
