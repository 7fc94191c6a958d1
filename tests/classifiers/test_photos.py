"""The real-photo pipeline: shapes, determinism by seed, correlated frames, argument errors."""

from __future__ import annotations

import numpy as np
import pytest

from classifiers.photos import PHOTO_CONDITIONS, PHOTOS, photo, photo_sequence, photo_snapshots


def test_every_photograph_loads_as_bgr_float():
    for name in PHOTOS:
        img = photo(name)
        assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32 and img.max() <= 255


@pytest.mark.parametrize("preset", list(PHOTO_CONDITIONS))
def test_a_sequence_has_the_asked_shape_and_is_a_function_of_its_seed(preset):
    seq = photo_sequence("coffee", 5, preset, seed=3, index=1, size=64)
    assert seq.shape == (5, 64, 64, 3) and seq.dtype == np.uint8
    np.testing.assert_array_equal(seq, photo_sequence("coffee", 5, preset, seed=3, index=1, size=64))
    assert not np.array_equal(seq, photo_sequence("coffee", 5, preset, seed=4, index=1, size=64))
    assert not np.array_equal(seq, photo_sequence("coffee", 5, preset, seed=3, index=2, size=64))


def test_frames_of_one_sequence_are_closer_than_frames_of_two():
    a = photo_sequence("astronaut", 4, "degraded", seed=0, index=0, size=64).astype(float)
    b = photo_sequence("astronaut", 4, "degraded", seed=0, index=1, size=64).astype(float)
    within = np.abs(a[1:] - a[:-1]).mean()
    across = np.abs(a - b).mean()
    assert within < across


def test_the_degraded_preset_is_darker_than_the_training_preset():
    train = photo_snapshots("chelsea", 8, "training", seed=0, size=48)
    degraded = photo_snapshots("chelsea", 8, "degraded", seed=0, size=48)
    assert train.shape == degraded.shape == (8, 48, 48, 3)
    assert degraded.mean() < train.mean()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"name": "lena"}, "name: expected one of"),
        ({"frames": 0}, "frames"),
        ({"seed": -1}, "seed"),
        ({"size": 4}, "size"),
        ({"conditions": "foggy"}, "preset: expected one of"),
        ({"conditions": 3}, "conditions: expected"),
    ],
)
def test_bad_arguments_fail_naming_the_argument(kwargs, match):
    args = {"name": "rocket", "frames": 2, "conditions": "degraded", "seed": 0, **kwargs}
    with pytest.raises(ValueError, match=match):
        photo_sequence(**args)


def test_snapshots_need_a_positive_count():
    with pytest.raises(ValueError, match="count"):
        photo_snapshots("rocket", 0, "training", seed=0)
