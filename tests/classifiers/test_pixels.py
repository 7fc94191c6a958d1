"""The renderer's compiled pixel kernels give the bytes of the numpy expressions they replace."""

from __future__ import annotations

from unittest import mock

import numpy as np

from classifiers.data.pixels import lit, lit_numpy, quantized, quantized_numpy, skip_normals


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
            for noise in (9.0, 0.0):
                ours, theirs = np.random.default_rng(7), np.random.default_rng(7)
                assert np.array_equal(quantized(img, ours, noise), quantized_numpy(img, theirs, noise))
                assert ours.bit_generator.state == theirs.bit_generator.state  # the same draws taken


def test_quantized_rounds_half_to_even_and_clips():
    img = np.array([0.5, 1.5, 2.5, -3.0, 254.5, 255.5, 300.0, -0.4, 7.49999]).reshape(1, 3, 3)
    assert quantized(img, np.random.default_rng(0), 0.0).ravel().tolist() == [0, 2, 2, 0, 254, 255, 255, 0, 7]


def test_skip_normals_advances_the_generator_as_numpy_draws_do():
    ours, theirs = np.random.default_rng(3), np.random.default_rng(3)
    skip_normals(ours, 1001)
    theirs.standard_normal(1001)
    assert ours.bit_generator.state == theirs.bit_generator.state
    assert ours.standard_normal() == theirs.standard_normal()
    skip_normals(ours, 0)
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_frames_are_the_same_bytes_as_with_the_numpy_expressions():
    from classifiers.data import render_images, render_sequence
    from classifiers.data import render as module

    def frames():
        return [
            render_sequence("ambulance", 6, "mission", seed=3, index=1),
            render_sequence("food_crate", 6, "training", seed=0, index=2),
            render_sequence("ambulance", 6, "mission", seed=3, index=1, start=4),  # skips frames 0-3's noise
            render_images("medical_copter", 3, "mission", seed=5),
        ]

    compiled = frames()
    numpy_skip = lambda rng, count: rng.standard_normal(count)  # noqa: E731
    with mock.patch.multiple(module.pixels, lit=lit_numpy, quantized=quantized_numpy, skip_normals=numpy_skip):
        reference = frames()
    assert all(np.array_equal(a, b) for a, b in zip(compiled, reference))
