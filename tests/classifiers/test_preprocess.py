"""Preprocessing geometry, augmentation, normalisation and input validation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from classifiers import augment, center_crop, crop_box, normalize
from classifiers.preprocess import as_image_batch, normalized_numpy


def test_crop_box_geometry():
    # 240 x 320 frame: centred square of side 240, padded 10 % each side -> side 288 around the centre.
    assert crop_box((240, 320, 3), 0.1) == pytest.approx((16.0, -24.0, 304.0, 264.0))
    assert crop_box((240, 320, 3), 0.0) == pytest.approx((40.0, 0.0, 280.0, 240.0))
    # An object box: square on its longer side, padded.
    assert crop_box((100, 100), 0.1, (10, 20, 50, 40)) == pytest.approx((6.0, 6.0, 54.0, 54.0))


def test_center_crop_maps_box_to_output():
    img = np.zeros((240, 320, 3), np.uint8)
    img[:, 160:] = 255  # right half white
    img[100:140, 140:180] = (0, 0, 255)  # red square at the centre
    img[0] = 77  # a grey top row, replicated above the frame
    out = center_crop(img, 288, 0.1)  # 1:1 scale: crop covers x in [16, 304), y in [-24, 264)
    assert out.shape == (288, 288, 3) and out.dtype == np.uint8
    assert (out[124:164, 124:164] == (0, 0, 255)).all()  # centre square stays centred, same size
    assert (out[25:120, 150] == 255).all() and (out[25:120, 140] == 0).all()  # the white edge at x = 160 -> 144
    assert (out[:25, 10] == 77).all()  # y = -24 .. 0: the top row replicated
    small = center_crop(img, 144, 0.1)
    assert (small[65:79, 65:79, 2] > 200).all() and (small[65:79, 65:79, 0] < 60).all()


def test_augment_seeded_and_mirrors():
    img = np.zeros((240, 320, 3), np.uint8)
    img[:, :100] = 255  # left side white
    a = [augment(img, np.random.default_rng(5), 64) for _ in range(2)]
    assert np.array_equal(a[0], a[1])
    rng = np.random.default_rng(0)
    outs = [augment(img, rng, 64, scale=(1.0, 1.0)) for _ in range(40)]
    left_white = [o[:, :8].mean() > 200 for o in outs]
    right_white = [o[:, -8:].mean() > 200 for o in outs]
    assert any(left_white) and any(right_white)  # both orientations occur
    assert all(lw != rw for lw, rw in zip(left_white, right_white))


def test_normalize_layout():
    crops = np.zeros((2, 4, 4, 3), np.uint8)
    crops[..., 0] = 10  # blue
    crops[..., 2] = 250  # red
    x = normalize(crops, mean=(127.0, 127.0, 127.0), std=(128.0, 128.0, 128.0))
    assert x.shape == (2, 3, 4, 4) and x.dtype == torch.float32
    assert torch.allclose(x[:, 0], torch.tensor((250 - 127) / 128))  # channel 0 is red (RGB)
    assert torch.allclose(x[:, 2], torch.tensor((10 - 127) / 128))


def test_as_image_batch_forms_and_errors():
    img = np.zeros((8, 9, 3), np.uint8)
    assert len(as_image_batch(img)) == 1
    assert len(as_image_batch([img, img])) == 2
    assert len(as_image_batch(np.stack([img] * 3))) == 3
    assert len(as_image_batch(torch.zeros(2, 8, 9, 3, dtype=torch.uint8))) == 2
    with pytest.raises(TypeError, match="uint8"):
        as_image_batch(img.astype(np.float32))
    with pytest.raises(TypeError, match="uint8"):
        as_image_batch(torch.zeros(1, 8, 8, 3))
    with pytest.raises(ValueError, match="3 BGR channels"):
        as_image_batch(np.zeros((8, 8, 4), np.uint8))
    with pytest.raises(ValueError, match="shape"):
        as_image_batch(np.zeros((8, 8), np.uint8))
    with pytest.raises(ValueError, match="empty"):
        as_image_batch([])
    with pytest.raises(ValueError, match="empty"):
        as_image_batch(np.zeros((0, 8, 8, 3), np.uint8))
    with pytest.raises(TypeError, match="images"):
        as_image_batch("frame.png")
    with pytest.raises(ValueError, match="padding"):
        crop_box((10, 10), -0.1)
    with pytest.raises(ValueError, match="box"):
        crop_box((10, 10), 0.1, (5, 5, 5, 9))


def test_normalize_equals_its_numpy_expression_bit_for_bit():
    crops = np.random.default_rng(0).integers(0, 256, size=(3, 17, 19, 3), dtype=np.uint8)
    mean, std = (0.485 * 255, 0.456 * 255, 0.406 * 255), (0.229 * 255, 0.224 * 255, 0.225 * 255)
    expected = normalized_numpy(crops, np.asarray(mean, np.float32), 1.0 / np.asarray(std, np.float32))
    for given, want in ((crops, expected), (list(crops), expected), (crops[:, ::-1], expected[:, ::-1])):
        x = normalize(given, mean, std)  # an array, a list and a strided view
        assert x.is_contiguous(memory_format=torch.channels_last)
        assert np.array_equal(x.permute(0, 2, 3, 1).numpy(), want)
