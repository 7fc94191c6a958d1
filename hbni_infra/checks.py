"""Validation of scalar arguments at a public boundary, with messages that name the argument.

Python, numpy and 0-d torch numbers are all accepted (``np.float32(0.9)``, ``torch.tensor(3)``);
booleans are not numbers here. Each function returns the plain Python value (a ``torch.device`` for
:func:`as_device`).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Any

import torch


def _scalar(value: Any) -> Any:
    """A 0-d tensor's Python value; anything else unchanged."""
    if isinstance(value, torch.Tensor) and value.dim() == 0:
        return value.item()
    return value


def as_int(name: str, value: Any, minimum: int | None = None) -> int:
    """``value`` as an ``int`` (``>= minimum`` when given), else ``TypeError``/``ValueError`` naming ``name``."""
    value = _scalar(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an int, got {value!r} ({type(value).__name__})")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"{name}: expected an int >= {minimum}, got {value}")
    return value


def as_float(
    name: str,
    value: Any,
    low: float = -math.inf,
    high: float = math.inf,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """``value`` as a finite ``float`` in the interval from ``low`` to ``high`` (closed unless ``*_open``).

    Raises:
        TypeError: not a real number (booleans and strings included).
        ValueError: NaN, infinite, or outside the interval; the message names ``name`` and the interval.
    """
    value = _scalar(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a number, got {value!r} ({type(value).__name__})")
    value = float(value)
    above = value > low if low_open else value >= low
    below = value < high if high_open else value <= high
    if not (math.isfinite(value) and above and below):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise ValueError(f"{name}: expected a finite number in {interval}, got {value}")
    return value


SEED_LIMIT = 2**63
"""Seeds are ints in ``[0, SEED_LIMIT)``: every torch generator, numba kernel and :mod:`hbni_infra.streams` takes them."""


def as_seed(name: str, value: Any, limit: int = SEED_LIMIT) -> int:
    """``value`` as a seed, an ``int`` in ``[0, limit)``; ``TypeError``/``ValueError`` naming ``name`` otherwise
    (a negative or huge int would be wrapped or refused deep inside torch or numpy)."""
    value = as_int(name, value)
    if not 0 <= value < limit:
        raise ValueError(f"{name}: expected a seed, an int in [0, 2**{limit.bit_length() - 1}), got {value}")
    return value


def as_generator(name: str, value: Any, device: torch.device | str | None = None) -> torch.Generator | None:
    """``value`` as a ``torch.Generator`` (on ``device`` when given); never ``None``, which would draw from torch's
    global stream, except where ``device`` is ``meta`` (shapes only, nothing is drawn).

    Raises:
        TypeError: not a ``torch.Generator`` (``None``, a seed); the message says how to make one.
        ValueError: a generator of another device than ``device``.
    """
    device = None if device is None else torch.device(device)
    if value is None and device is not None and device.type == "meta":
        return None
    if not isinstance(value, torch.Generator):
        raise TypeError(
            f"{name}: expected a torch.Generator (e.g. hbni_infra.streams.torch_stream(seed, 'name')), "
            f"got {value!r} ({type(value).__name__})"
        )
    if device is not None and value.device.type != device.type:
        raise ValueError(f"{name}: expected a generator on {device.type!r}, got one on {value.device.type!r}")
    return value


def as_probability(name: str, value: Any, allow_zero: bool = True) -> float:
    """``value`` as a probability in ``[0, 1]`` (``(0, 1]`` when ``allow_zero`` is false)."""
    return as_float(name, value, 0.0, 1.0, low_open=not allow_zero)


def as_choice(name: str, value: Any, choices: Sequence[Any]) -> Any:
    """``value`` when it is one of ``choices``, else ``ValueError`` naming ``name`` and listing the choices."""
    if value not in tuple(choices):
        raise ValueError(f"{name}: expected one of {list(choices)}, got {value!r}")
    return value


def as_names(name: str, names: Any, count: int, at_least: bool = False) -> tuple[str, ...] | None:
    """``names`` as a tuple of ``count`` distinct strings (at least ``count`` with ``at_least``); ``None`` stays
    ``None`` (unnamed). ``TypeError`` for a string or a non-sequence, ``ValueError`` for the wrong count or repeats."""
    if names is None:
        return None
    if isinstance(names, str) or not hasattr(names, "__iter__"):
        raise TypeError(f"{name}: expected a sequence of names, got {type(names).__name__}")
    names = tuple(names)
    if (
        not all(isinstance(n, str) for n in names)
        or len(set(names)) != len(names)
        or (len(names) < count if at_least else len(names) != count)
    ):
        raise ValueError(f"{name}: expected {'at least ' if at_least else ''}{count} distinct names, got {list(names)}")
    return names


def as_device(name: str, value: Any) -> torch.device:
    """``value`` (a ``str`` such as ``"cuda:0"`` or a ``torch.device``) as a device this machine can allocate on.

    Raises:
        TypeError: not a ``str`` or ``torch.device``.
        ValueError: not a device name, or a device this torch build or machine lacks (``"cuda"`` without CUDA).
    """
    if not isinstance(value, (str, torch.device)):
        raise TypeError(f"{name}: expected a str or torch.device, got {value!r} ({type(value).__name__})")
    try:
        device = torch.device(value)
    except RuntimeError as exc:
        raise ValueError(f"{name}: expected a torch device such as 'cpu' or 'cuda', got {value!r}") from exc
    try:
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as exc:
        reason = str(exc).split(". ")[0] or type(exc).__name__
        raise ValueError(f"{name}: device {str(device)!r} is not available here ({reason})") from exc
    return device


def first_difference(a: Sequence[Any], b: Sequence[Any]) -> int:
    """The first index where the sequences differ (the shorter one's length when one extends the other)."""
    return next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
