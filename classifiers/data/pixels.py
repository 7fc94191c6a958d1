"""The renderer's per-pixel arithmetic, compiled with numba: one pass to composite and light a frame, one to draw
its sensor noise, add it and quantise.

Each kernel computes what the numpy expression in its docstring computes, in the same precisions and order
(float32 compositing, float64 light), so a frame has the same bytes as with those expressions; the kernels only
skip the temporaries (numpy wrote ten full-frame arrays a frame, half the renderer's time). The noise comes from
the frame's own ``numpy.random.Generator``, drawn in numba (which runs NumPy's normal sampler on the same bit
generator, so the draws and the generator's state after them are NumPy's) a pixel at a time instead of into a
full-frame array. :func:`lit_numpy` and :func:`quantized_numpy` are those expressions, the oracle of the tests
and of ``benchmarks/bench_render.py``. The kernels release the GIL: threads render side by side.
"""

from __future__ import annotations

import numpy as np

from hbni_infra.numba_cache import use_cache_dir

use_cache_dir()  # before any cached function is decorated

from numba import njit  # noqa: E402

__all__ = ["lit", "lit_numpy", "quantized", "quantized_numpy", "skip_normals"]


@njit(cache=True, nogil=True)
def lit(
    obj: np.ndarray,
    alpha: np.ndarray,
    background: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    cos: float,
    sin: float,
    shading: float,
    gain: float,
    cast: np.ndarray,
) -> np.ndarray:
    """``(obj * a + background * (1 - a)) * light``, float64 ``(H, W, 3)``.

    ``obj`` uint8 ``(H, W, 3)``, ``alpha`` float32 ``(H, W)`` (``a``) and ``background`` float32 ``(H, W, 3)``
    (any strides) composite in float32; ``light = gain * (1 + shading * ramp)[..., None] * cast`` in float64,
    with ``ramp = (cos * xs[None, :] + sin * ys[:, None]) * 2``, ``xs`` float32 ``(W,)`` and ``ys`` float32
    ``(H,)`` the pixel coordinates as shares of the frame less 1/2, ``cast`` float32 ``(3,)``.
    """
    h, w = alpha.shape
    out = np.empty((h, w, 3), np.float64)
    one = np.float32(1.0)
    for y in range(h):
        row = sin * np.float64(ys[y])
        for x in range(w):
            a = alpha[y, x]
            level = gain * (1.0 + shading * ((cos * np.float64(xs[x]) + row) * 2.0))
            for k in range(3):
                mixed = np.float32(obj[y, x, k]) * a + background[y, x, k] * (one - a)
                out[y, x, k] = np.float64(mixed) * (level * np.float64(cast[k]))
    return out


@njit(cache=True, nogil=True)
def quantized(img: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """``np.clip(np.rint(img + rng.normal(0, noise, img.shape).astype(np.float32)), 0, 255).astype(np.uint8)``,
    ``(H, W, 3)``; ``noise`` 0 draws nothing and adds nothing.

    ``img`` float64 ``(H, W, 3)``; ``noise`` the sensor noise's standard deviation in 0..255 pixel units.
    """
    h, w, _ = img.shape
    out = np.empty((h, w, 3), np.uint8)
    noisy = noise > 0
    for y in range(h):
        for x in range(w):
            for k in range(3):
                v = img[y, x, k]
                if noisy:
                    v = v + np.float64(np.float32(0.0 + noise * rng.standard_normal()))
                out[y, x, k] = np.uint8(min(max(np.rint(v), 0.0), 255.0))
    return out


@njit(cache=True, nogil=True)
def skip_normals(rng: np.random.Generator, count: int) -> None:
    """Advance ``rng`` as ``rng.standard_normal(count)`` does, keeping no draw."""
    for _ in range(count):
        rng.standard_normal()


def lit_numpy(
    obj: np.ndarray,
    alpha: np.ndarray,
    background: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    cos: float,
    sin: float,
    shading: float,
    gain: float,
    cast: np.ndarray,
) -> np.ndarray:
    """:func:`lit` in numpy expressions (the oracle)."""
    a = alpha[..., None]
    img = obj.astype(np.float32) * a + background * (1 - a)
    ramp = (np.float64(cos) * xs[None, :] + np.float64(sin) * ys[:, None]) * 2
    return img * (gain * (1 + shading * ramp)[..., None] * cast)


def quantized_numpy(img: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """:func:`quantized` in numpy expressions (the oracle)."""
    if noise > 0:
        img = img + rng.normal(0, noise, size=img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
