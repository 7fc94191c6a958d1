"""The renderer and the image-folder reader: layout, determinism, identical conditions, errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from classifiers.data import (
    FRAME_SHAPE,
    MISSION,
    OBJECTS,
    TRAINING,
    ImageFolder,
    get_conditions,
    render_images,
    render_sequence,
    write_image_folder,
)
from classifiers.data.sprites import draw_sprite


def test_write_and_read_image_folder(tmp_path):
    root = write_image_folder(tmp_path / "data", ["irobot", "food_crate"], n_per_class=3, seed=2)
    assert sorted(p.name for p in root.iterdir()) == ["food_crate", "irobot"]
    assert sorted(p.name for p in (root / "irobot").iterdir()) == [f"irobot_{i:04d}.png" for i in range(3)]
    folder = ImageFolder(root)
    assert folder.classes == ["food_crate", "irobot"] and len(folder) == 6
    images, labels = folder.load()
    assert labels.tolist() == [0, 0, 0, 1, 1, 1]
    assert images[0].shape == (*FRAME_SHAPE, 3) and images[0].dtype == np.uint8
    np.testing.assert_array_equal(images[3], render_images("irobot", 1, "training", seed=2)[0])  # PNG is lossless


def test_renderer_seeded_and_conditions_shared_across_classes():
    a = render_images("quadrotor", 2, "mission", seed=5)
    assert np.array_equal(a, render_images("quadrotor", 2, "mission", seed=5))
    assert not np.array_equal(a, render_images("quadrotor", 2, "mission", seed=6))
    b = render_images("racecar", 2, "mission", seed=5)
    # Same draws for every class: corners (no object there) match up to the sensor noise.
    corner = (slice(0, 20), slice(0, 20))
    assert np.abs(a[0][corner].astype(int) - b[0][corner].astype(int)).mean() < 2
    assert np.abs(a[0].astype(int) - b[0].astype(int)).mean() > 2  # the objects differ


def test_classes_distinct_and_conditions_differ():
    sprites = [draw_sprite(name)[0].astype(float) for name in OBJECTS]
    for i in range(len(sprites)):
        for j in range(i + 1, len(sprites)):
            assert np.abs(sprites[i] - sprites[j]).mean() > 10, (OBJECTS[i], OBJECTS[j])
    bright = render_images("ambulance", 4, TRAINING, seed=0).astype(float)
    dim = render_images("ambulance", 4, MISSION, seed=0).astype(float)
    assert bright.mean() > 1.5 * dim.mean()  # dim light

    def high_freq(x):  # relative energy of pixel-to-pixel changes (noise, texture)
        return np.abs(np.diff(x, axis=2)).mean() / x.mean()

    assert high_freq(dim) > high_freq(bright)


def test_sequence_moves_and_light_drifts():
    seq = render_sequence("news_copter", 12, "mission", seed=1, index=4)
    assert seq.shape == (12, *FRAME_SHAPE, 3) and seq.dtype == np.uint8
    assert np.array_equal(seq, render_sequence("news_copter", 12, "mission", seed=1, index=4))
    steps = np.abs(np.diff(seq.astype(float), axis=0)).mean(axis=(1, 2, 3))
    assert (steps > 1).all()  # every frame differs from the last
    brightness = seq.reshape(12, -1).mean(1)
    assert brightness.max() / brightness.min() > 1.05  # lighting drifts


def test_errors(tmp_path):
    with pytest.raises(ValueError, match="name"):
        render_images("bicycle", 1)
    with pytest.raises(ValueError, match="n_frames"):
        render_sequence("irobot", 0)
    with pytest.raises(ValueError, match="n"):
        render_images("irobot", -1)
    with pytest.raises(ValueError, match="conditions"):
        render_images("irobot", 1, "foggy")
    with pytest.raises(ValueError, match="background"):
        get_conditions("training", background="stars")
    with pytest.raises(ValueError, match="noise"):
        get_conditions("mission", noise=(5.0, 1.0))
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['fog'\]"):
        get_conditions("mission", fog=(0.1, 0.2))
    with pytest.raises(ValueError, match="name"):
        write_image_folder(tmp_path / "x", ["irobot", "unicorn"], 1)
    assert not (tmp_path / "x").exists()  # validated before writing anything
    with pytest.raises(FileNotFoundError, match="root"):
        ImageFolder(tmp_path / "nope")
    (tmp_path / "empty" / "cls").mkdir(parents=True)
    with pytest.raises(ValueError, match="has no images .* neither in <class>/ folders nor directly in it"):
        ImageFolder(tmp_path / "empty")
    (tmp_path / "empty" / "cls" / "broken.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="decoded"):
        ImageFolder(tmp_path / "empty")[0]


def test_a_flat_folder_of_frames_is_read_unlabelled_in_name_order(tmp_path):
    frames = render_sequence("ambulance", 12, "mission", seed=3)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), frame)  # frame_2 must come before frame_10
    folder = ImageFolder(tmp_path)
    assert not folder.labelled and folder.classes == []
    assert [p.name for p, _ in folder.samples] == [f"frame_{i}.png" for i in range(12)]
    images, labels = folder.load()
    assert labels.tolist() == [-1] * 12
    assert all(np.array_equal(a, b) for a, b in zip(images, frames))  # PNG is lossless
    (tmp_path / "cls").mkdir()
    cv2.imwrite(str(tmp_path / "cls" / "x.png"), frames[0])
    with pytest.raises(ValueError, match="both <class>/ folders and loose images"):
        ImageFolder(tmp_path)
