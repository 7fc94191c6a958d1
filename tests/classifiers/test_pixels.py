"""The renderer's compiled pixel kernels give the bytes of the numpy expressions they replace."""

from __future__ import annotations

from unittest import mock

import numpy as np

from classifiers.data.pixels import lit, lit_numpy, quantized, quantized_numpy


def test_lit_and_quantized_equal_the_numpy_expressions():
    rng = np.random.default_rng(1)
    h, w = 23, 31
    obj = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    alpha = rng.uniform(0, 1, size=(h, w)).astype(np.float32)
    alpha[:3] = 0.0
    alpha[-3:] = 1.0
    big = rng.uniform(0, 255, size=(h + 9, w + 7, 3)).astype(np.float32)
    xs = np.arange(w, dtype=np.float32) / w - 0.5
    ys = np.arange(h, dtype=np.float32) / h - 0.5
    cast = (1 + rng.uniform(-0.2, 0.2, 3)).astype(np.float32)
    for background in (big[:h, :w].copy(), big[4 : 4 + h, 3 : 3 + w]):  # contiguous, and a strided pan
        for angle, shading, gain in ((0.3, 0.4, 1.1), (4.0, 0.0, 0.6)):
            args = (obj, alpha, background, xs, ys, float(np.cos(angle)), float(np.sin(angle)), shading, gain, cast)
            img = lit(*args)
            assert img.dtype == np.float64 and np.array_equal(img, lit_numpy(*args))
            noise = rng.normal(0, 9.0, size=img.shape)
            assert np.array_equal(quantized(img, noise), quantized_numpy(img, noise))
            none = np.zeros((0, 0, 3))
            assert np.array_equal(quantized(img, none), quantized_numpy(img, none))


def test_quantized_rounds_half_to_even_and_clips():
    img = np.array([0.5, 1.5, 2.5, -3.0, 254.5, 255.5, 300.0, -0.4, 7.49999]).reshape(1, 3, 3)
    assert quantized(img, np.zeros((0, 0, 3))).ravel().tolist() == [0, 2, 2, 0, 254, 255, 255, 0, 7]


def test_frames_are_the_same_bytes_as_with_the_numpy_expressions():
    from classifiers.data import render_images, render_sequence
    from classifiers.data import render as module

    def frames():
        return [
            render_sequence("ambulance", 6, "mission", seed=3, index=1),
            render_sequence("food_crate", 6, "training", seed=0, index=2),
            render_images("medical_copter", 3, "mission", seed=5),
        ]

    compiled = frames()
    with mock.patch.multiple(module.pixels, lit=lit_numpy, quantized=quantized_numpy):
        reference = frames()
    assert all(np.array_equal(a, b) for a, b in zip(compiled, reference))
