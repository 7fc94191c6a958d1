"""Imaging conditions: camera pose ranges, light, background, blur and noise.

A :class:`Conditions` is applied identically to every object class. Two presets follow
the paper's setting: ``TRAINING`` (bright light, plain background, near-canonical views:
the snapshots the head is trained on) and ``MISSION`` (dim light that drifts over a
sequence, motion blur, sensor noise, a cluttered textured background, wide viewpoints).
Ranges are ``(low, high)`` of uniform draws.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

__all__ = ["Conditions", "MISSION", "TRAINING", "get_conditions"]

Range = tuple[float, float]


@dataclass(frozen=True)
class Conditions:
    """How a frame is imaged.

    Attributes:
        name: label of the preset.
        scale: object width as a fraction of the frame height.
        yaw, pitch, roll: object rotation in degrees (yaw/pitch foreshorten, roll turns in-plane).
        offset: centre offset as a fraction of the frame height (both axes).
        gain: global light level (1 = as drawn).
        drift: relative amplitude of the slow light oscillation over a sequence.
        cast: maximum per-channel colour-cast deviation of the light.
        shading: strength of a linear illumination gradient across the frame.
        background: ``"plain"`` or ``"textured"``.
        blur: motion-blur streak length in pixels (0 = none).
        noise: sensor-noise standard deviation in 0..255 units.
    """

    name: str
    scale: Range
    yaw: Range
    pitch: Range
    roll: Range
    offset: Range
    gain: Range
    drift: float
    cast: float
    shading: float
    background: str
    blur: Range
    noise: Range

    def __post_init__(self) -> None:
        if self.background not in ("plain", "textured"):
            raise ValueError(f"background: expected 'plain' or 'textured', got {self.background!r}")
        for key in ("scale", "yaw", "pitch", "roll", "offset", "gain", "blur", "noise"):
            lo, hi = getattr(self, key)
            if lo > hi:
                raise ValueError(f"{key}: expected low <= high, got ({lo}, {hi})")
        if self.scale[0] <= 0 or self.gain[0] <= 0 or self.blur[0] < 0 or self.noise[0] < 0:
            raise ValueError("scale and gain must be > 0; blur and noise >= 0")

    def to_dict(self) -> dict:
        return asdict(self)


TRAINING = Conditions(
    name="training",
    scale=(0.75, 0.95),
    yaw=(-20.0, 20.0),
    pitch=(-10.0, 10.0),
    roll=(-6.0, 6.0),
    offset=(-0.04, 0.04),
    gain=(0.95, 1.15),
    drift=0.0,
    cast=0.04,
    shading=0.05,
    background="plain",
    blur=(0.0, 0.0),
    noise=(0.0, 1.0),
)

MISSION = Conditions(
    name="mission",
    scale=(0.5, 0.9),
    yaw=(-45.0, 45.0),
    pitch=(-25.0, 25.0),
    roll=(-15.0, 15.0),
    offset=(-0.1, 0.1),
    gain=(0.3, 0.6),
    drift=0.3,
    cast=0.15,
    shading=0.4,
    background="textured",
    blur=(2.0, 10.0),
    noise=(5.0, 12.0),
)

_PRESETS = {"training": TRAINING, "mission": MISSION}


def get_conditions(name: str | Conditions, **overrides) -> Conditions:
    """A preset by name (``"training"`` or ``"mission"``), optionally with fields replaced."""
    if isinstance(name, Conditions):
        base = name
    elif name in _PRESETS:
        base = _PRESETS[name]
    else:
        raise ValueError(f"conditions: expected one of {sorted(_PRESETS)} or a Conditions, got {name!r}")
    unknown = sorted(set(overrides) - set(Conditions.__dataclass_fields__))
    if unknown:
        raise ValueError(
            f"conditions: unknown field(s) {unknown}; expected some of {list(Conditions.__dataclass_fields__)}"
        )
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    return replace(base, **overrides) if overrides else base
