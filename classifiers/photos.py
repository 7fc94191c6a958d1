"""Frames of real photographs (scikit-image's bundled colour images) seen by a degraded moving camera.

Each class is one photograph. A *sequence* is one pass of the camera over it: a square crop
whose centre drifts along a straight path with per-frame jitter, light that starts dim and
drifts, one colour cast, motion blur along the drift, Gaussian sensor noise and an occluding
patch that slides across the view. Everything but the per-frame jitter, blur length and
noise is drawn once per sequence, so the frames of a sequence are correlated.

:data:`PHOTO_CONDITIONS` holds the two presets: ``"training"`` (mild, for the SVM head's
snapshots) and ``"degraded"`` (calibration and held-out sequences). Frames are
``(size, size, 3)`` uint8 BGR arrays, like :mod:`classifiers.data`'s renderer.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache

import cv2
import numpy as np

from hbni_infra.checks import as_int
from hbni_infra.optional import require
from hbni_infra.streams import numpy_generator

#: the classes: scikit-image's bundled colour photographs, by their ``skimage.data`` name
PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field", "immunohistochemistry")


@dataclass(frozen=True)
class PhotoConditions:
    """Degradation of one preset; ``(lo, hi)`` pairs are uniform ranges drawn once per sequence.

    Units: ``crop`` and ``drift``/``jitter`` are shares of the photograph's short side (``drift``
    per frame), ``gain`` multiplies intensities (``gain_drift`` is the per-frame sd of its random
    walk, relative), ``cast`` the largest relative change of one BGR channel, ``blur`` the motion
    blur length in output pixels, ``noise`` the sensor noise sd in grey levels, ``occluder`` the
    occluding patch's side as a share of the frame (``0`` for none).
    """

    crop: tuple[float, float]
    drift: tuple[float, float]
    jitter: float
    gain: tuple[float, float]
    gain_drift: float
    cast: float
    blur: tuple[float, float]
    noise: tuple[float, float]
    occluder: tuple[float, float]

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


PHOTO_CONDITIONS: dict[str, PhotoConditions] = {
    "training": PhotoConditions(
        crop=(0.3, 0.9),
        drift=(0.0, 0.0),
        jitter=0.0,
        gain=(0.6, 1.1),
        gain_drift=0.0,
        cast=0.1,
        blur=(0.0, 3.0),
        noise=(0.0, 5.0),
        occluder=(0.0, 0.0),
    ),
    "degraded": PhotoConditions(
        crop=(0.3, 0.6),
        drift=(0.005, 0.02),
        jitter=0.02,
        gain=(0.3, 0.7),
        gain_drift=0.05,
        cast=0.25,
        blur=(2.0, 8.0),
        noise=(6.0, 15.0),
        occluder=(0.2, 0.4),
    ),
}


@lru_cache(maxsize=None)
def photo(name: str) -> np.ndarray:
    """The photograph ``name`` of :data:`PHOTOS` as a float32 BGR array ``(H, W, 3)`` in grey levels."""
    if name not in PHOTOS:
        raise ValueError(f"name: expected one of {list(PHOTOS)}, got {name!r}")
    data = require("skimage.data", "experiments", "the sample photographs")
    rgb = getattr(data, name)()[..., :3]
    return np.ascontiguousarray(rgb[..., ::-1], dtype=np.float32)


def get_photo_conditions(preset: str) -> PhotoConditions:
    if preset not in PHOTO_CONDITIONS:
        raise ValueError(f"preset: expected one of {list(PHOTO_CONDITIONS)}, got {preset!r}")
    return PHOTO_CONDITIONS[preset]


def photo_sequence(
    name: str, frames: int, conditions: PhotoConditions | str, seed: int, index: int = 0, size: int = 160
) -> np.ndarray:
    """``frames`` correlated frames ``(frames, size, size, 3)`` uint8 BGR of photograph ``name``.

    The sequence is a function of ``(name, seed, index)`` and the conditions only.
    """
    frames, seed, index = as_int("frames", frames, 1), as_int("seed", seed, 0), as_int("index", index, 0)
    size = as_int("size", size, 16)
    c = get_photo_conditions(conditions) if isinstance(conditions, str) else conditions
    if not isinstance(c, PhotoConditions):
        raise ValueError(f"conditions: expected a PhotoConditions or a preset name, got {type(conditions).__name__}")
    img = photo(name)
    rng = numpy_generator(seed, PHOTOS.index(name), index)
    h, w = img.shape[:2]
    short = min(h, w)
    side = rng.uniform(*c.crop) * short
    centre = np.array([rng.uniform(side / 2, w - side / 2), rng.uniform(side / 2, h - side / 2)])
    heading = rng.uniform(0, 2 * np.pi)
    step = rng.uniform(*c.drift) * short * np.array([np.cos(heading), np.sin(heading)])
    gain = rng.uniform(*c.gain)
    cast = 1 + rng.uniform(-c.cast, c.cast, 3).astype(np.float32)
    blur_lo, blur_hi = c.blur
    noise = rng.uniform(*c.noise)
    occ_side = rng.uniform(*c.occluder) * size
    occ = rng.uniform(0, size - occ_side, 2) if occ_side >= 1 else None
    occ_step = rng.normal(0, size * 0.02, 2)
    occ_colour = rng.uniform(0, 255, 3)
    out = np.empty((frames, size, size, 3), dtype=np.uint8)
    for f in range(frames):
        pos = centre + step * f + rng.normal(0, c.jitter * short, 2)
        pos = np.clip(pos, side / 2, [w - side / 2, h - side / 2])  # the camera bumps along the photograph's edge
        frame = _crop(img, pos, side, size)
        frame = _motion_blur(frame, rng.uniform(blur_lo, blur_hi), heading + rng.normal(0, 0.3))
        frame = frame * (gain * cast) + rng.normal(0, noise, frame.shape).astype(np.float32)
        if occ is not None:
            x, y = (np.clip(occ + occ_step * f, 0, size - occ_side)).astype(int)
            frame[y : y + int(occ_side), x : x + int(occ_side)] = occ_colour
        out[f] = np.clip(frame, 0, 255).astype(np.uint8)
        gain *= float(np.exp(rng.normal(0, c.gain_drift)))
    return out


def photo_snapshots(name: str, count: int, conditions: PhotoConditions | str, seed: int, size: int = 160) -> np.ndarray:
    """``count`` independent frames ``(count, size, size, 3)`` of ``name``: the first frame of ``count`` sequences."""
    count = as_int("count", count, 1)
    return np.stack([photo_sequence(name, 1, conditions, seed, index=i, size=size)[0] for i in range(count)])


def _crop(img: np.ndarray, centre: np.ndarray, side: float, size: int) -> np.ndarray:
    scale = size / side
    m = np.array([[scale, 0, size / 2 - scale * centre[0]], [0, scale, size / 2 - scale * centre[1]]], dtype=np.float32)
    return cv2.warpAffine(img, m, (size, size), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REFLECT)


def _motion_blur(frame: np.ndarray, length: float, angle: float) -> np.ndarray:
    n = int(round(length))
    if n < 2:
        return frame
    kernel = np.zeros((n, n), dtype=np.float32)
    r = (n - 1) / 2
    for t in np.linspace(-r, r, 2 * n):
        kernel[int(round(r + t * np.sin(angle))), int(round(r + t * np.cos(angle)))] = 1
    return cv2.filter2D(frame, -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)
