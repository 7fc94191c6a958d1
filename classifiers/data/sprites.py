"""Canonical drawings of the object classes (OpenCV primitives on a 256 x 256 canvas).

Each drawer paints a colour image and an opacity mask together, so the object can be
warped into any camera view and composited over any background. The three vehicles of
the paper's hardware study are drawn as seen by a robot's camera (iRobot Create from a
raised three-quarter view, quadrotor from slightly above, racecar from the side); the six
disaster-relief objects are drawn from the side.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

__all__ = ["SPRITE_SIZE", "SPRITES", "draw_sprite"]

SPRITE_SIZE = 256
_AA = cv2.LINE_AA


class _Painter:
    """Draws on a BGR canvas and its opacity mask at once."""

    def __init__(self, size: int = SPRITE_SIZE):
        self.img = np.zeros((size, size, 3), np.uint8)
        self.mask = np.zeros((size, size), np.uint8)

    def poly(self, pts, color, closed_fill: bool = True, thickness: int = 2) -> None:
        pts = np.asarray(pts, np.int32).reshape(-1, 1, 2)
        if closed_fill:
            cv2.fillPoly(self.img, [pts], color, _AA)
            cv2.fillPoly(self.mask, [pts], 255, _AA)
        else:
            cv2.polylines(self.img, [pts], False, color, thickness, _AA)
            cv2.polylines(self.mask, [pts], False, 255, thickness, _AA)

    def rect(self, x0, y0, x1, y1, color, thickness: int = -1) -> None:
        cv2.rectangle(self.img, (x0, y0), (x1, y1), color, thickness, _AA)
        cv2.rectangle(self.mask, (x0, y0), (x1, y1), 255, thickness, _AA)

    def circle(self, c, r, color, thickness: int = -1) -> None:
        cv2.circle(self.img, c, r, color, thickness, _AA)
        cv2.circle(self.mask, c, r, 255, thickness, _AA)

    def ellipse(self, c, axes, color, angle: float = 0, start: int = 0, end: int = 360, thickness: int = -1) -> None:
        cv2.ellipse(self.img, c, axes, angle, start, end, color, thickness, _AA)
        cv2.ellipse(self.mask, c, axes, angle, start, end, 255, thickness, _AA)

    def line(self, p, q, color, thickness: int = 2) -> None:
        cv2.line(self.img, p, q, color, thickness, _AA)
        cv2.line(self.mask, p, q, 255, thickness, _AA)

    def text(self, s, org, scale, color, thickness: int = 2) -> None:
        cv2.putText(self.img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, thickness, _AA)
        cv2.putText(self.mask, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, thickness, _AA)

    def cross(self, cx, cy, arm, width, color) -> None:
        self.rect(cx - width, cy - arm, cx + width, cy + arm, color)
        self.rect(cx - arm, cy - width, cx + arm, cy + width, color)


# Colours are BGR.
_BLACK, _WHITE, _RED, _BLUE = (25, 25, 25), (245, 245, 245), (40, 40, 215), (200, 90, 30)


def _wheel(p: _Painter, c, r) -> None:
    p.circle(c, r, _BLACK)
    p.circle(c, int(r * 0.5), (170, 170, 170))
    p.circle(c, int(r * 0.18), (60, 60, 60))


def _irobot(p: _Painter) -> None:
    cx, cy = 128, 120
    p.ellipse((cx, cy + 34), (108, 46), (60, 60, 60))  # cylinder side, dark
    p.rect(cx - 108, cy, cx + 108, cy + 34, (60, 60, 60))
    p.ellipse((cx, cy + 34), (108, 46), (90, 90, 90), start=0, end=180, thickness=3)
    p.ellipse((cx, cy), (108, 46), (205, 205, 200))  # top disc, light grey
    p.ellipse((cx, cy), (108, 46), (45, 45, 45), start=180, end=360, thickness=9)  # front bumper
    p.rect(cx - 48, cy - 20, cx + 48, cy + 20, (120, 120, 118))  # cargo bay
    p.rect(cx - 40, cy - 14, cx + 40, cy + 14, (85, 85, 85))
    for dx in (-28, 0, 28):  # mounting holes
        p.circle((cx + dx, cy), 4, (30, 30, 30))
    p.circle((cx + 70, cy + 14), 8, (60, 200, 60))  # power LED
    p.circle((cx - 72, cy + 12), 6, (0, 170, 240))  # status LED
    p.rect(cx - 14, cy + 46, cx + 14, cy + 62, (160, 160, 160))  # caster plate


def _quadrotor(p: _Painter) -> None:
    cx, cy = 128, 128
    ends = [(50, 62), (206, 62), (50, 194), (206, 194)]
    for ex, ey in ends:
        p.line((cx, cy), (ex, ey), (30, 30, 30), 6)  # arms
    for ex, ey in ends:
        p.ellipse((ex, ey), (42, 16), (150, 150, 150), thickness=2)  # rotor disc guard
        p.line((ex - 38, ey - 6), (ex + 38, ey + 6), (40, 40, 40), 4)  # blades
        p.circle((ex, ey), 8, (20, 20, 20))  # motor
    p.rect(cx - 20, cy - 16, cx + 20, cy + 16, (20, 110, 240))  # orange body plate
    p.rect(cx - 12, cy - 26, cx + 12, cy - 16, (30, 30, 30))  # battery
    p.line((cx - 22, cy + 16), (cx - 34, cy + 52), (30, 30, 30), 4)  # landing legs
    p.line((cx + 22, cy + 16), (cx + 34, cy + 52), (30, 30, 30), 4)
    p.line((cx - 44, cy + 52), (cx - 24, cy + 52), (30, 30, 30), 4)
    p.line((cx + 24, cy + 52), (cx + 44, cy + 52), (30, 30, 30), 4)


def _racecar(p: _Painter) -> None:
    body = [(16, 150), (30, 118), (92, 108), (120, 80), (176, 80), (200, 108), (240, 114), (242, 150)]
    p.poly(body, (30, 30, 210))  # red body
    p.poly([(126, 86), (172, 86), (190, 108), (112, 108)], (190, 140, 60))  # windshield
    p.rect(210, 70, 246, 78, _BLACK)  # rear spoiler
    p.rect(224, 78, 230, 112, _BLACK)
    p.circle((150, 130), 15, _WHITE)  # race number
    p.text("7", (142, 139), 0.7, _BLACK, 2)
    p.rect(20, 138, 238, 144, (20, 180, 240))  # yellow side stripe
    _wheel(p, (62, 152), 26)
    _wheel(p, (200, 152), 26)


def _ambulance(p: _Painter) -> None:
    p.rect(14, 60, 180, 170, _WHITE)  # box
    p.poly([(180, 90), (222, 94), (244, 130), (244, 170), (180, 170)], _WHITE)  # cab
    p.poly([(186, 98), (218, 100), (234, 128), (186, 128)], (120, 80, 40))  # cab window
    p.rect(14, 140, 244, 150, _RED)  # red stripe
    p.cross(96, 104, 30, 10, _RED)
    p.rect(150, 48, 178, 60, (240, 120, 20))  # blue beacon
    _wheel(p, (60, 172), 22)
    _wheel(p, (206, 172), 22)


def _police_car(p: _Painter) -> None:
    p.poly([(12, 160), (12, 124), (60, 116), (92, 84), (172, 84), (204, 116), (244, 124), (244, 160)], _BLACK)
    p.rect(66, 116, 196, 156, _WHITE)  # white doors
    p.poly([(98, 90), (166, 90), (190, 114), (78, 114)], (120, 90, 60))  # windows
    p.line((132, 90), (132, 114), _BLACK, 4)
    p.rect(104, 70, 128, 84, _RED)  # light bar: red | blue
    p.rect(128, 70, 152, 84, (230, 80, 10))
    p.text("POLICE", (80, 146), 0.75, _BLACK, 2)
    _wheel(p, (58, 162), 23)
    _wheel(p, (200, 162), 23)


def _helicopter(p: _Painter, body, stripe, mark: Callable[[_Painter], None]) -> None:
    p.line((20, 56), (236, 56), (40, 40, 40), 5)  # main rotor
    p.rect(124, 56, 134, 80, (40, 40, 40))  # mast
    p.poly([(60, 110), (100, 82), (170, 80), (196, 104), (196, 140), (160, 156), (76, 156), (56, 136)], body)
    p.poly([(190, 106), (240, 112), (240, 124), (190, 130)], body)  # tail boom
    p.circle((234, 108), 14, (60, 60, 60), thickness=3)  # tail rotor
    p.poly([(66, 110), (100, 88), (124, 88), (124, 118), (64, 118)], (140, 110, 70))  # cockpit glass
    p.rect(56, 132, 196, 140, stripe)
    p.line((74, 156), (70, 178), (40, 40, 40), 4)  # skids
    p.line((168, 156), (172, 178), (40, 40, 40), 4)
    p.line((52, 178), (196, 178), (40, 40, 40), 5)
    mark(p)


def _medical_copter(p: _Painter) -> None:
    _helicopter(p, _WHITE, _RED, lambda q: q.cross(158, 110, 18, 6, _RED))


def _news_copter(p: _Painter) -> None:
    def mark(q: _Painter) -> None:
        q.text("NEWS", (128, 122), 0.6, (40, 220, 250), 2)
        q.rect(80, 156, 100, 166, _BLACK)  # camera pod
        q.circle((80, 161), 7, (90, 90, 90))

    _helicopter(p, (120, 50, 20), (40, 220, 250), mark)


def _food_crate(p: _Painter) -> None:
    p.rect(30, 60, 226, 206, (40, 95, 150))  # wood
    for y in (96, 132, 168):  # plank gaps
        p.line((30, y), (226, y), (20, 50, 85), 3)
    p.rect(30, 60, 226, 206, (25, 60, 100), thickness=8)  # frame
    p.line((38, 198), (218, 68), (25, 70, 110), 12)  # diagonal brace
    p.text("FOOD", (70, 146), 1.3, (20, 20, 20), 4)


def _medical_crate(p: _Painter) -> None:
    p.rect(28, 70, 228, 200, (230, 236, 236))  # plastic case
    p.rect(28, 70, 228, 200, (60, 140, 40), thickness=10)  # green rim
    p.rect(100, 50, 156, 62, (60, 60, 60), thickness=6)  # handle
    p.rect(44, 96, 62, 110, (60, 60, 60))  # latches
    p.rect(194, 96, 212, 110, (60, 60, 60))
    p.cross(128, 138, 42, 14, _RED)


SPRITES: dict[str, Callable[[_Painter], None]] = {
    "irobot": _irobot,
    "quadrotor": _quadrotor,
    "racecar": _racecar,
    "ambulance": _ambulance,
    "police_car": _police_car,
    "medical_copter": _medical_copter,
    "news_copter": _news_copter,
    "food_crate": _food_crate,
    "medical_crate": _medical_crate,
}


_CACHE: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def draw_sprite(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The canonical drawing of class ``name``: BGR ``(256, 256, 3)`` uint8 and opacity ``(256, 256)`` in [0, 1]."""
    if name not in SPRITES:
        raise ValueError(f"name: unknown object class {name!r}; expected one of {sorted(SPRITES)}")
    if name not in _CACHE:
        painter = _Painter()
        SPRITES[name](painter)
        _CACHE[name] = (painter.img, painter.mask.astype(np.float32) / 255.0)
    img, mask = _CACHE[name]
    return img.copy(), mask.copy()
