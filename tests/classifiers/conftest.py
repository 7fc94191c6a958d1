"""Session fixtures: one backbone load and one set of backbone features shared by the tests."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from classifiers import FrameClassifier, load_backbone
from classifiers.data import render_images

VEHICLES = ("irobot", "quadrotor", "racecar")  # the classes of the paper's hardware study


@pytest.fixture(scope="session")
def backbone():
    return load_backbone()


@pytest.fixture(scope="session")
def frame_classifier(backbone) -> FrameClassifier:
    """An unfitted float classifier on the shared backbone (the backbone cache makes this free): its features are the
    float32 oracle's, with no calibration to make (``test_quantize.py`` tests the 8-bit path)."""
    return FrameClassifier(precision="float")


@pytest.fixture(scope="session")
def vehicle_features(frame_classifier):
    """Backbone features of rendered snapshots of the three vehicles, as in the perception study.

    Returns ``(x_train (120, 1000), y_train, x_test (180, 1000), y_test)``: 40 training-condition
    snapshots per class to train on and 60 mission-condition snapshots per class to test on (dim,
    blurred, noisy, cluttered: a hard test, so accuracies are far from 100 % and comparable).
    """
    out = []
    for seed, n, conditions in ((0, 40, "training"), (1, 60, "mission")):
        images, labels = [], []
        for k, name in enumerate(VEHICLES):
            images += list(render_images(name, n, conditions, seed=seed))
            labels += [k] * n
        out += [frame_classifier.features(images), np.array(labels)]
    return tuple(out)


@pytest.fixture(scope="session")
def standardized_features(vehicle_features):
    """The same features standardised with the training set's mean and sd (as the pipeline does)."""
    x_tr, y_tr, x_te, y_te = vehicle_features
    mean, sd = x_tr.double().mean(0), x_tr.double().std(0).clamp_min(1e-6)
    return ((x_tr - mean) / sd).numpy(), y_tr, ((x_te - mean) / sd).numpy(), y_te


@pytest.fixture(scope="session")
def fitted_classifier(frame_classifier, vehicle_features):
    x_tr, y_tr, _, _ = vehicle_features
    names = [VEHICLES[k] for k in y_tr]
    clf = FrameClassifier(seed=3, precision="float")
    return clf.fit_features(x_tr, names)


torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
