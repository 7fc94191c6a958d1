"""Render object classes into camera frames under training or mission conditions.

A frame is the class's canonical drawing (:mod:`classifiers.data.sprites`) placed on a
plane in front of a pinhole camera (pose: scale, yaw, pitch, roll, offset), composited
over a background, lit (gain, colour cast, illumination gradient), motion-blurred and
corrupted by sensor noise. All random draws for image ``i`` (or sequence ``i``) come from
``hbni_infra.streams.numpy_generator(seed, i)`` and do not depend on the class, so every class
is seen under exactly the same poses, light, backgrounds, blur and noise.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from classifiers.data import pixels
from classifiers.data.conditions import Conditions, get_conditions
from classifiers.data.sprites import SPRITE_SIZE, SPRITES, draw_sprite
from hbni_infra.files import atomic_write_bytes
from hbni_infra.streams import numpy_generator

__all__ = [
    "FRAME_SHAPE",
    "OBJECTS",
    "Look",
    "Pose",
    "render_frame",
    "render_images",
    "render_sequence",
    "write_image_folder",
]

#: the object kinds the renderer can draw; a caller says which of them make up its classes
OBJECTS = tuple(SPRITES)
FRAME_SHAPE = (240, 320)  # (H, W) pixels


@dataclass(frozen=True)
class Pose:
    """Object pose relative to the camera (see :class:`Conditions` for units)."""

    scale: float
    yaw: float
    pitch: float
    roll: float
    dx: float
    dy: float


@dataclass(frozen=True)
class Look:
    """Photometric state of one frame: light level, colour cast, gradient, blur streak, noise."""

    gain: float
    cast: tuple[float, float, float]
    shade_dir: float
    shading: float
    blur: float
    blur_angle: float
    noise: float


def _check_class(name: str) -> None:
    if name not in SPRITES:
        raise ValueError(f"name: unknown object class {name!r}; expected one of {list(OBJECTS)}")


def _rng(seed: int, index: int) -> np.random.Generator:
    return numpy_generator(seed, index)


def _u(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def _homography(pose: Pose, shape: tuple[int, int]) -> np.ndarray:
    """Sprite pixels -> frame pixels for an object plane of unit width at the pose."""
    h, w = shape
    f = 1.5 * h
    y, p, r = np.deg2rad([pose.yaw, pose.pitch, pose.roll])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rot = rz @ ry @ rx
    z = f / (pose.scale * h)  # unit width spans scale * h pixels when frontal
    t = np.array([pose.dx * h * z / f, pose.dy * h * z / f, z])
    k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    plane = np.column_stack([rot[:, 0], rot[:, 1], t])
    s = np.array([[1 / SPRITE_SIZE, 0, -0.5], [0, 1 / SPRITE_SIZE, -0.5], [0, 0, 1]])
    return k @ plane @ s


def _plain_background(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    base = rng.uniform(195, 235) + rng.uniform(-8, 8, size=3)
    return np.broadcast_to(base, (*shape, 3)).astype(np.float32).copy()


def _textured_background(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A cluttered scene: multi-scale colour noise, floor tiles, and random objects and cables."""
    h, w = shape
    img = np.zeros((h, w, 3), np.float32)
    for cells, amp in ((3, 70.0), (8, 40.0), (24, 20.0)):
        grid = rng.normal(0, amp, size=(cells, max(2, cells * w // h), 3)).astype(np.float32)
        img += cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    img += rng.uniform(90, 160, size=3).astype(np.float32)
    canvas = np.clip(img, 0, 255).astype(np.uint8)
    tile = int(rng.integers(24, 64))
    tile_color = tuple(int(c) for c in rng.integers(30, 120, size=3))
    for x in range(int(rng.integers(0, tile)), w, tile):
        cv2.line(canvas, (x, 0), (x, h), tile_color, 1, cv2.LINE_AA)
    for y in range(int(rng.integers(0, tile)), h, tile):
        cv2.line(canvas, (0, y), (w, y), tile_color, 1, cv2.LINE_AA)
    for _ in range(int(rng.integers(10, 20))):
        color = tuple(int(c) for c in rng.integers(0, 256, size=3))
        kind = rng.integers(4)
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        size = int(rng.integers(6, h // 4))
        if kind == 0:
            cv2.rectangle(canvas, (cx, cy), (cx + size, cy + int(rng.integers(6, h // 4))), color, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.circle(canvas, (cx, cy), size // 2, color, int(rng.choice([-1, 2, 4])), cv2.LINE_AA)
        elif kind == 2:
            end = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            cv2.line(canvas, (cx, cy), end, color, int(rng.integers(2, 7)), cv2.LINE_AA)
        else:
            pts = rng.integers(-size, size, size=(int(rng.integers(3, 6)), 2)) + np.array([cx, cy])
            cv2.fillPoly(canvas, [pts.astype(np.int32).reshape(-1, 1, 2)], color, cv2.LINE_AA)
    return canvas.astype(np.float32)


def _background(cond: Conditions, rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    return _plain_background(rng, shape) if cond.background == "plain" else _textured_background(rng, shape)


def _sample_pose(cond: Conditions, rng: np.random.Generator) -> Pose:
    return Pose(
        _u(rng, cond.scale),
        _u(rng, cond.yaw),
        _u(rng, cond.pitch),
        _u(rng, cond.roll),
        _u(rng, cond.offset),
        _u(rng, cond.offset),
    )


def _sample_look(cond: Conditions, rng: np.random.Generator) -> Look:
    cast = tuple(float(c) for c in 1 + rng.uniform(-cond.cast, cond.cast, size=3))
    return Look(
        _u(rng, cond.gain),
        cast,
        float(rng.uniform(0, 2 * np.pi)),
        float(rng.uniform(0, cond.shading)),
        _u(rng, cond.blur),
        float(rng.uniform(0, 180)),
        _u(rng, cond.noise),
    )


def _motion_kernel(length: float, angle: float) -> np.ndarray:
    n = int(np.ceil(length)) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    dx, dy = np.cos(np.deg2rad(angle)) * length / 2, np.sin(np.deg2rad(angle)) * length / 2
    cv2.line(k, (int(round(c - dx)), int(round(c - dy))), (int(round(c + dx)), int(round(c + dy))), 1.0, 1, cv2.LINE_AA)
    return k / k.sum()


def render_frame(name: str, pose: Pose, look: Look, background: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uint8 BGR frame of class ``name`` over ``background`` (float32 ``(H, W, 3)``).

    ``rng`` draws the sensor noise only.
    """
    _check_class(name)
    shape = background.shape[:2]
    h, w = shape
    sprite, alpha = draw_sprite(name)
    hmat = _homography(pose, shape)
    obj = cv2.warpPerspective(sprite, hmat, (w, h), flags=cv2.INTER_LINEAR)
    a = cv2.warpPerspective(alpha, hmat, (w, h), flags=cv2.INTER_LINEAR)
    xs = np.arange(w, dtype=np.float32) / w - 0.5
    ys = np.arange(h, dtype=np.float32) / h - 0.5
    cast = np.asarray(look.cast, np.float32)
    cos, sin = float(np.cos(look.shade_dir)), float(np.sin(look.shade_dir))
    img = pixels.lit(obj, a, background, xs, ys, cos, sin, float(look.shading), float(look.gain), cast)
    if look.blur >= 1.5:
        img = cv2.filter2D(img, -1, _motion_kernel(look.blur, look.blur_angle), borderType=cv2.BORDER_REFLECT)
    return pixels.quantized(img, rng, float(look.noise))


def render_images(
    name: str,
    n: int,
    conditions: str | Conditions = "training",
    seed: int = 0,
    start: int = 0,
    shape: tuple[int, int] = FRAME_SHAPE,
) -> np.ndarray:
    """``n`` independent snapshots ``(n, H, W, 3)`` uint8 BGR of class ``name``.

    Snapshot ``i`` uses draws seeded by ``(seed, start + i)``, the same for every class.
    """
    _check_class(name)
    if n < 0:
        raise ValueError(f"n: expected >= 0, got {n}")
    cond = get_conditions(conditions)
    out = np.empty((n, *shape, 3), np.uint8)
    for i in range(n):
        rng = _rng(seed, start + i)
        pose, look, bg = _sample_pose(cond, rng), _sample_look(cond, rng), _background(cond, rng, shape)
        out[i] = render_frame(name, pose, look, bg, rng)
    return out


def _smooth_path(rng: np.random.Generator, lo: float, hi: float, t: np.ndarray) -> np.ndarray:
    """A smooth path inside [lo, hi]: linear from one draw to another plus a gentle wobble."""
    a, b = rng.uniform(lo, hi, size=2)
    wobble = 0.15 * (hi - lo) * np.sin(2 * np.pi * (rng.uniform(0.3, 1.2) * t + rng.uniform()))
    return np.clip(a + (b - a) * t + wobble, lo, hi)


def render_sequence(
    name: str,
    n_frames: int,
    conditions: str | Conditions = "mission",
    seed: int = 0,
    index: int = 0,
    shape: tuple[int, int] = FRAME_SHAPE,
    start: int = 0,
    stop: int | None = None,
) -> np.ndarray:
    """Frames ``(n_frames, H, W, 3)`` uint8 BGR of one object seen from a camera moving along a path.

    Scale, angles and offset follow smooth paths through the condition ranges; the
    background pans with the camera; the light level drifts slowly (``conditions.drift``);
    motion blur grows with the camera's image-plane speed along its direction. Draws are
    seeded by ``(seed, index)``, the same for every class.

    ``start``, ``stop``: render only frames ``start .. stop - 1`` (default: all), ``(stop - start, H, W, 3)``,
    the same pixels as those frames of the whole sequence (an earlier frame only advances the sensor noise's
    stream), so a sequence can be rendered a block of frames at a time.
    """
    _check_class(name)
    if n_frames < 1:
        raise ValueError(f"n_frames: expected >= 1, got {n_frames}")
    stop = n_frames if stop is None else stop
    if not 0 <= start < stop <= n_frames:
        raise ValueError(f"start, stop: expected 0 <= start < stop <= n_frames = {n_frames}, got {start}, {stop}")
    cond = get_conditions(conditions)
    rng = _rng(seed, index)
    h, w = shape
    t = np.linspace(0.0, 1.0, n_frames)
    path = {k: _smooth_path(rng, *getattr(cond, k), t) for k in ("scale", "yaw", "pitch", "roll")}
    dx, dy = _smooth_path(rng, *cond.offset, t), _smooth_path(rng, *cond.offset, t)
    base = _sample_look(cond, rng)
    period, phase = rng.uniform(0.5, 1.5), rng.uniform(0, 2 * np.pi)
    wander = 0.05 * np.cumsum(rng.normal(size=n_frames)) / np.sqrt(n_frames)  # slow random walk
    gain = base.gain * np.exp(cond.drift * np.sin(2 * np.pi * t / period + phase) + wander)
    pan = 0.35 * h
    pan_dir = rng.uniform(-1, 1, size=2)
    big = _background(cond, rng, (h + int(2 * pan) + 2, w + int(2 * pan) + 2))
    frames = np.empty((stop - start, h, w, 3), np.uint8)
    for i in range(stop):
        if i < start:  # a frame not asked for: only its sensor noise's draws, to keep the stream's place
            if base.noise > 0:
                pixels.skip_normals(rng, h * w * 3)
            continue
        px, py = (int(round(pan * (1 + 2 * d * (t[i] - 0.5)))) for d in pan_dir)
        bg = big[py : py + h, px : px + w]
        j = max(i - 1, 0)
        speed = np.hypot(dx[i] - dx[j], dy[i] - dy[j]) * h + abs(path["yaw"][i] - path["yaw"][j]) * 0.3
        blur = min(base.blur + speed, cond.blur[1] * 1.5) if cond.blur[1] > 0 else 0.0
        angle = float(np.rad2deg(np.arctan2(dy[i] - dy[j], dx[i] - dx[j] + 1e-9))) if i > 0 else base.blur_angle
        look = Look(float(gain[i]), base.cast, base.shade_dir, base.shading, blur, angle, base.noise)
        pose = Pose(path["scale"][i], path["yaw"][i], path["pitch"][i], path["roll"][i], dx[i], dy[i])
        frames[i - start] = render_frame(name, pose, look, bg, rng)
    return frames


def write_image_folder(
    root: str | os.PathLike,
    classes: Sequence[str],
    n_per_class: int = 10,
    conditions: str | Conditions = "training",
    seed: int = 0,
    shape: tuple[int, int] = FRAME_SHAPE,
) -> Path:
    """Render ``n_per_class`` snapshots per class into ``root/<class>/<class>_<i>.png``; returns ``root``."""
    root = Path(root)
    for name in classes:
        _check_class(name)
    for name in classes:
        for i, img in enumerate(render_images(name, n_per_class, conditions, seed, shape=shape)):
            ok, buf = cv2.imencode(".png", img)
            if not ok:
                raise OSError(f"could not encode {name} image {i} as PNG")
            atomic_write_bytes(root / name / f"{name}_{i:04d}.png", buf.tobytes())
    return root
