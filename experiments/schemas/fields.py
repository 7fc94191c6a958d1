"""Schema fields that carry their range in their metadata, and the walk that checks a settings object.

A field is declared with its type and, where its range is narrower than the type, with a constructor of this
module: ``frames: int = count()`` (an int >= 1), ``threshold: float = probability()`` (in (0, 1]),
``planning_model: str = choice(PLANNING_MODELS)``. Every constructor leaves the default ``MISSING``: the values
live in ``conf/``. :func:`check_ranges` runs every field's check, the blocks below a block first, then the block's
own ``check(path)`` for the rules that tie its fields together, and names the key in the error it raises.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

from omegaconf import MISSING

from experiments.schemas.targets import join_key
from hbni_infra.checks import as_choice, as_float, as_int, as_probability

Check = Callable[[str, Any], Any]
"""``check(name, value)``: raises ``ValueError`` (naming ``name``) when ``value`` is out of range."""


def ranged(check: Check, default: Any = MISSING) -> Any:
    """A field whose value ``check(name, value)`` accepts (default ``MISSING``: set in ``conf/``)."""
    return dataclasses.field(default=default, metadata={"check": check})


def count(minimum: int = 1, optional: bool = False, default: Any = MISSING) -> Any:
    """An int of at least ``minimum`` (or ``None`` when ``optional``)."""
    return ranged(lambda name, value: None if optional and value is None else as_int(name, value, minimum), default)


def probability() -> Any:
    """A probability in ``(0, 1]``."""
    return ranged(lambda name, value: as_probability(name, value, allow_zero=False))


def optional_probability() -> Any:
    """A probability in ``(0, 1]``, or ``None``."""
    return ranged(lambda name, value: None if value is None else as_probability(name, value, allow_zero=False))


def probabilities() -> Any:
    """A list of probabilities, each in ``(0, 1]``."""
    return ranged(lambda name, values: [as_probability(name, v, allow_zero=False) for v in values])


def bounded(low: float, high: float) -> Any:
    """A finite float in ``[low, high]``."""
    return ranged(lambda name, value: as_float(name, value, low, high))


def choice(options: Sequence[Any] | Callable[[], Sequence[Any]], default: Any = MISSING) -> Any:
    """One of ``options`` (or of what ``options()`` returns when it is called: a registry read at check time)."""
    return ranged(lambda name, value: as_choice(name, value, options() if callable(options) else options), default)


def check_ranges(settings: Any, path: str = "") -> Any:
    """Check every field of ``settings`` (a schema's dataclass, as :func:`experiments.schemas.typed_settings` builds
    it) and of the blocks below it, each block's inner blocks (also the dataclass values of a dict field) before its
    own fields and its ``check(path)``. Raises ``ValueError`` naming the key; returns ``settings``."""
    if isinstance(settings, dict):
        for key, value in settings.items():
            check_ranges(value, f"{path}.{key}")
        return settings
    if not dataclasses.is_dataclass(settings):
        return settings
    fields = dataclasses.fields(settings)
    for f in fields:
        check_ranges(getattr(settings, f.name), f"{path}.{f.name}" if path else f.name)
    try:
        for f in fields:
            if "check" in f.metadata:
                f.metadata["check"](f.name, getattr(settings, f.name))
        if hasattr(settings, "check"):
            settings.check(path)
    except ValueError as exc:
        message = str(exc)
        if not path or message.startswith(f"{path}.") or message.startswith(f"{path}:"):
            raise
        raise ValueError(join_key(path, message, [f.name for f in fields])) from None
    return settings
