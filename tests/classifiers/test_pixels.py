"""The renderer's compiled pixel kernels give the bytes of the numpy expressions they replace."""

from __future__ import annotations

import numpy as np

from classifiers.data.pixels import lit, quantized


def _lit_numpy(obj, alpha, background, xs, ys, cos, sin, shading, gain, cast):
    a = alpha[..., None]
    img = obj.astype(np.float32) * a + background * (1 - a)
    ramp = (np.float64(cos) * xs[None, :] + np.float64(sin) * ys[:, None]) * 2
    return img * (gain * (1 + shading * ramp)[..., None] * cast)


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
            assert img.dtype == np.float64 and np.array_equal(img, _lit_numpy(*args))
            noise = rng.normal(0, 9.0, size=img.shape)
            noisy = np.clip(np.rint(img + noise.astype(np.float32)), 0, 255).astype(np.uint8)
            assert np.array_equal(quantized(img, noise), noisy)
            assert np.array_equal(quantized(img, np.zeros((0, 0, 3))), np.clip(np.rint(img), 0, 255).astype(np.uint8))


def test_quantized_rounds_half_to_even_and_clips():
    img = np.array([0.5, 1.5, 2.5, -3.0, 254.5, 255.5, 300.0, -0.4, 7.49999]).reshape(1, 3, 3)
    assert quantized(img, np.zeros((0, 0, 3))).ravel().tolist() == [0, 2, 2, 0, 254, 255, 255, 0, 7]
