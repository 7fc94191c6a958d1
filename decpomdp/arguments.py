"""Argument checks at the planners' public boundary: numbers of any kind in, plain Python numbers out.

Numpy and torch scalars (and 0-d arrays/tensors) are accepted wherever a Python number is; strings,
booleans and containers are not. Every error names the argument and what was expected.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
import torch


def _scalar(value: Any) -> Any:
    """Unwrap a numpy/torch scalar or 0-d array/tensor to a Python scalar; anything else unchanged."""
    if isinstance(value, torch.Tensor) and value.dim() == 0:
        return value.item()
    if isinstance(value, (np.generic, np.ndarray)) and np.ndim(value) == 0:
        return value.item()
    return value


def as_int(name: str, value: Any, minimum: int | None = None) -> int:
    """``value`` as a Python int (>= ``minimum``); ``TypeError``/``ValueError`` naming ``name`` otherwise."""
    raw = _scalar(value)
    if isinstance(raw, bool) or not isinstance(raw, numbers.Integral):
        raise TypeError(f"{name}: expected an int, got {type(value).__name__} {value!r}")
    if minimum is not None and raw < minimum:
        raise ValueError(f"{name}: expected an int >= {minimum}, got {raw}")
    return int(raw)


def as_float(name: str, value: Any, low: float = -math.inf, high: float = math.inf,
             low_open: bool = False, high_open: bool = False) -> float:
    """``value`` as a finite Python float in the interval [low, high] (ends open as flagged)."""
    raw = _scalar(value)
    if isinstance(raw, bool) or not isinstance(raw, numbers.Real):
        raise TypeError(f"{name}: expected a number, got {type(value).__name__} {value!r}")
    out = float(raw)
    below = out <= low if low_open else out < low
    above = out >= high if high_open else out > high
    if math.isnan(out) or below or above or math.isinf(out):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise ValueError(f"{name}: expected a finite number in {interval}, got {value!r}")
    return out


def as_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of the strings ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name}: expected one of {choices}, got {value!r}")
    return value
