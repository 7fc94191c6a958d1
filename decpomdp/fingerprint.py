"""What produced a checkpoint: a flat, JSON-able description of a run, and the fields two descriptions differ in.

A checkpoint records its run's fingerprint, ``{"sizes": ..., "problem": ..., "config": ..., "seed": ...,
"init": ...}``; resuming it with a run whose fingerprint differs raises a ``ValueError`` that names
every differing field (``problem.env.horizon``, ``config.alpha``, ``seed``, ...).

The ``problem`` entry describes the evaluator: an object with a ``fingerprint()`` method describes
itself; any other object is described by its class and its public attributes, recursively (numbers,
strings and flags as they are, tensors and arrays by a SHA-256 of dtype, shape and bytes, functions by
their qualified name), so two Monte Carlo evaluators of Dec-Tiger at horizons 3 and 4 differ in
``problem.env.horizon``.
"""

from __future__ import annotations

import hashlib
import json
import types
from typing import Any

import numpy as np
import torch

_MAX_DEPTH = 4


def digest(*arrays: torch.Tensor | np.ndarray) -> str:
    """SHA-256 over the dtypes, shapes and bytes of ``arrays``."""
    h = hashlib.sha256()
    for a in arrays:
        arr = a.detach().cpu().contiguous().numpy() if isinstance(a, torch.Tensor) else np.ascontiguousarray(a)
        h.update(f"{arr.dtype}{arr.shape}".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _name(obj: Any) -> str:
    kind = obj if isinstance(obj, type) else type(obj)
    return f"{kind.__module__}.{kind.__qualname__}"


def describe(obj: Any) -> dict[str, Any]:
    """Flat description ``{dotted name: JSON value}`` of an evaluator (or any object), see the module doc."""
    out: dict[str, Any] = {}
    _describe(obj, "", out, set(), 0)
    return jsonable(out)


def _plain(obj: Any) -> bool:
    """Whether ``obj`` is made of JSON scalars, lists and string-keyed dicts only."""
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return True
    if isinstance(obj, (list, tuple)):
        return all(_plain(v) for v in obj)
    return isinstance(obj, dict) and all(isinstance(k, str) and _plain(v) for k, v in obj.items())


def _describe(obj: Any, prefix: str, out: dict[str, Any], seen: set[int], depth: int) -> None:
    key = prefix.rstrip(".") or "class"
    if obj is None or isinstance(obj, (bool, int, float, str)):
        out[key] = obj
    elif isinstance(obj, np.generic):
        out[key] = obj.item()
    elif isinstance(obj, (torch.Tensor, np.ndarray)):
        out[key] = "sha256:" + digest(obj)
    elif isinstance(obj, (list, tuple, dict)) and _plain(obj):
        out[key] = obj
    elif isinstance(obj, (types.FunctionType, types.MethodType, types.BuiltinFunctionType)):
        out[key] = f"{obj.__module__}.{obj.__qualname__}"
    elif callable(getattr(obj, "fingerprint", None)) and not isinstance(obj, type):
        for name, value in obj.fingerprint().items():
            _describe(value, f"{prefix}{name}.", out, seen, depth + 1)
    elif id(obj) in seen or depth > _MAX_DEPTH or not hasattr(obj, "__dict__"):
        out[key] = _name(obj)
    else:
        out[f"{prefix}class"] = _name(obj)
        for name, value in sorted(vars(obj).items()):
            if not name.startswith("_"):
                _describe(value, f"{prefix}{name}.", out, seen | {id(obj)}, depth + 1)


def jsonable(obj: Any) -> Any:
    """``obj`` as it reads back from JSON (tuples become lists), so fingerprints compare before and after saving."""
    return json.loads(json.dumps(obj))


def differences(recorded: Any, current: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """Every ``(dotted field, recorded value, current value)`` where two fingerprints differ."""
    if isinstance(recorded, dict) and isinstance(current, dict):
        out = []
        for name in sorted(set(recorded) | set(current), key=str):
            out += differences(recorded.get(name, "<missing>"), current.get(name, "<missing>"), f"{prefix}{name}.")
        return out
    return [] if recorded == current else [(prefix.rstrip("."), recorded, current)]


def check_same_run(path: str, recorded: Any, current: dict[str, Any]) -> None:
    """Raise ``ValueError`` naming each field where the checkpoint's fingerprint differs from this run's."""
    if not isinstance(recorded, dict):
        raise ValueError(f"checkpoint: {path!r} records no fingerprint of the run that wrote it")
    diff = differences(recorded, current)
    if diff:
        shown = "; ".join(f"{field}: checkpoint has {a!r}, this run has {b!r}" for field, a, b in diff[:5])
        more = f" (and {len(diff) - 5} more)" if len(diff) > 5 else ""
        raise ValueError(f"checkpoint: {path!r} was written by another run; {shown}{more}")
