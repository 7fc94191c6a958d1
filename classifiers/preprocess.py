"""Image preprocessing with OpenCV: the paper's padded centre crop, augmentation, normalisation.

Images are uint8 BGR arrays ``(H, W, 3)`` as OpenCV reads them. The crop is a square
centred on an object box (default: the centred square of side ``min(H, W)``) whose side is
the box's longer side plus ``padding`` of it on each side, i.e. ``(1 + 2 * padding) * side``.
Pixels outside the frame are replicated from its border. The crop is resized to the
backbone's input side with area interpolation.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import torch
from torch import Tensor

from hbni_infra.numba_cache import use_cache_dir

use_cache_dir()  # before any cached function is decorated

from numba import njit  # noqa: E402

__all__ = ["as_image_batch", "augment", "center_crop", "crop_box", "normalize", "normalized_numpy"]

Box = tuple[float, float, float, float]  # x0, y0, x1, y1 in pixels


def as_image_batch(images, name: str = "images") -> list[np.ndarray]:
    """Validate ``images`` and return a list of contiguous uint8 BGR ``(H, W, 3)`` arrays.

    Accepts one ``(H, W, 3)`` array, a list of them, or a ``(B, H, W, 3)`` uint8 array or tensor.

    Raises:
        TypeError: not an array/tensor/list, or dtype is not uint8.
        ValueError: empty batch, wrong number of dimensions or channels.
    """
    if isinstance(images, Tensor):
        if images.dtype != torch.uint8:
            raise TypeError(f"{name}: expected dtype uint8, got {images.dtype}")
        images = images.detach().cpu().numpy()
    if isinstance(images, np.ndarray):
        if images.ndim == 3:
            images = [images]
        elif images.ndim == 4:
            images = list(images)
        else:
            raise ValueError(f"{name}: expected (H, W, 3) or (B, H, W, 3), got shape {images.shape}")
    if not isinstance(images, Sequence):
        raise TypeError(f"{name}: expected an array, a tensor or a list of arrays, got {type(images).__name__}")
    if len(images) == 0:
        raise ValueError(f"{name}: empty batch")
    out = []
    for i, img in enumerate(images):
        if isinstance(img, Tensor):
            img = img.detach().cpu().numpy()
        if not isinstance(img, np.ndarray):
            raise TypeError(f"{name}[{i}]: expected a numpy array, got {type(img).__name__}")
        if img.dtype != np.uint8:
            raise TypeError(f"{name}[{i}]: expected dtype uint8 (BGR 0..255), got {img.dtype}")
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"{name}[{i}]: expected shape (H, W, 3) with 3 BGR channels, got {img.shape}")
        if img.shape[0] < 2 or img.shape[1] < 2:
            raise ValueError(f"{name}[{i}]: image too small, shape {img.shape}")
        out.append(np.ascontiguousarray(img))
    return out


def crop_box(shape: tuple[int, ...], padding: float = 0.1, box: Box | None = None) -> Box:
    """The square crop ``(x0, y0, x1, y1)`` for an image of ``shape`` (see the module docstring)."""
    if padding < 0:
        raise ValueError(f"padding: expected >= 0, got {padding}")
    h, w = shape[:2]
    if box is None:
        s = min(h, w)
        box = ((w - s) / 2, (h - s) / 2, (w + s) / 2, (h + s) / 2)
    x0, y0, x1, y1 = box
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"box: expected x1 > x0 and y1 > y0, got {box}")
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half = (1 + 2 * padding) * max(x1 - x0, y1 - y0) / 2
    return (cx - half, cy - half, cx + half, cy + half)


def _warp_square(image: np.ndarray, box: Box, size: int, mirror: bool = False) -> np.ndarray:
    """Resample the square ``box`` of ``image`` to ``(size, size, 3)``; border pixels replicate."""
    x0, y0, x1, y1 = box
    scale = size / (x1 - x0)
    sx = -scale if mirror else scale
    tx = (x1 * scale) if mirror else (-x0 * scale)
    m = np.array([[sx, 0.0, tx], [0.0, scale, -y0 * scale]])
    if scale < 0.5:  # anti-alias before downsampling (sigma = (factor - 1) / 2, as scikit-image)
        image = cv2.GaussianBlur(image, (0, 0), (1 / scale - 1) / 2)
    # Pixel centres: map destination centre (u + 0.5) to source centre (x + 0.5).
    m[:, 2] += 0.5 * (m[:, 0] + m[:, 1]) - 0.5
    return cv2.warpAffine(image, m, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def center_crop(image: np.ndarray, size: int = 224, padding: float = 0.1, box: Box | None = None) -> np.ndarray:
    """The paper's centre crop with ``padding`` (fraction of the box side, each side), as ``(size, size, 3)``."""
    return _warp_square(image, crop_box(image.shape, padding, box), size)


def augment(
    image: np.ndarray,
    rng: np.random.Generator,
    size: int = 224,
    padding: float = 0.1,
    scale: tuple[float, float] = (0.8, 1.0),
    box: Box | None = None,
) -> np.ndarray:
    """A random crop (side ``scale`` times the padded crop's, anywhere inside it) mirrored with p = 1/2."""
    x0, y0, x1, y1 = crop_box(image.shape, padding, box)
    side = (x1 - x0) * rng.uniform(*scale)
    ox, oy = rng.uniform(0, (x1 - x0) - side, size=2)
    mirror = bool(rng.random() < 0.5)
    return _warp_square(image, (x0 + ox, y0 + oy, x0 + ox + side, y0 + oy + side), size, mirror)


def normalize(crops: np.ndarray | Sequence[np.ndarray], mean: Sequence[float], std: Sequence[float]) -> Tensor:
    """uint8 BGR crops ``(B, S, S, 3)`` -> float32 RGB ``(B, 3, S, S)``, ``(x - mean) / std`` per channel.

    The result is a channels-last view (the memory layout the backbone runs in), computed in one compiled pass
    with the bytes of :func:`normalized_numpy`.
    """
    arr = np.ascontiguousarray(crops if isinstance(crops, np.ndarray) else np.stack(list(crops)))
    m = np.asarray(mean, np.float32)
    inv = 1.0 / np.asarray(std, np.float32)
    return torch.from_numpy(_normalized(arr, m, inv)).permute(0, 3, 1, 2)


@njit(cache=True)
def _normalized(arr: np.ndarray, mean: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """``(arr[..., ::-1].astype(float32) - mean) * inv``: uint8 BGR ``(B, S, S, 3)`` -> float32 RGB, same shape."""
    out = np.empty(arr.shape, np.float32)
    b, h, w, _ = arr.shape
    for i in range(b):
        for y in range(h):
            for x in range(w):
                for k in range(3):
                    out[i, y, x, k] = (np.float32(arr[i, y, x, 2 - k]) - mean[k]) * inv[k]
    return out


def normalized_numpy(arr: np.ndarray, mean: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """:func:`_normalized` in numpy expressions (the oracle of the tests and of ``benchmarks/bench_render.py``)."""
    return (arr[..., ::-1].astype(np.float32) - mean) * inv
