"""The perception steps of the experiments: a classifier trained on rendered snapshots, rendered sequences classified
on one thread or several."""

from __future__ import annotations

import pytest
import torch
from omegaconf import OmegaConf

from classifiers import FrameClassifier
from classifiers.data import get_conditions, render_sequence
from experiments.steps.classification import sequence_outputs, train_classifier

CLASSES = ["ambulance", "police_car", "food_crate"]


@pytest.fixture(scope="module")
def clf() -> FrameClassifier:
    config = OmegaConf.create({"_target_": "classifiers.FrameClassifier", "seed": 0})
    return train_classifier(config, CLASSES, per_class=6, augment=0, seed=0, progress=False)


def _outputs(clf: FrameClassifier, workers: int) -> tuple[torch.Tensor, object]:
    return sequence_outputs(clf, CLASSES, 2, 3, get_conditions("mission"), 5, False, "test", workers)


def test_outputs_are_the_classified_sequences_in_the_callers_class_order(clf):
    outputs, thumbs = _outputs(clf, 1)
    assert outputs.shape == (3, 2, 3, 3)
    frames = render_sequence("food_crate", 3, get_conditions("mission"), seed=5, index=1)
    order = [clf.classes_.index(name) for name in CLASSES]
    assert torch.equal(outputs[2, 1], clf.predict_proba(frames)[:, order])
    assert (thumbs[2, 1] == frames).all()


def test_threads_give_the_same_outputs_bit_for_bit(clf):
    one, thumbs_one = _outputs(clf, 1)
    two, thumbs_two = _outputs(clf, 2)
    assert torch.equal(one, two)
    assert all((a == b).all() for a, b in zip(thumbs_one.ravel(), thumbs_two.ravel()))


def test_bad_workers_are_clear_errors(clf):
    with pytest.raises(ValueError, match="workers: expected an int >= 1"):
        _outputs(clf, 0)
    clf.threads = 2
    try:
        with pytest.raises(ValueError, match="workers: 2 threads need a classifier on one torch thread"):
            _outputs(clf, 2)
        assert torch.equal(_outputs(clf, None)[0], _outputs(clf, 1)[0])  # the default falls back to one worker
    finally:
        clf.threads = 1
