"""The identity of an evaluator or a problem, for checkpoint fingerprints (:mod:`hbni_infra.fingerprint`).

A checkpoint records its run's fingerprint, whose ``problem`` entry is :func:`describe` of the
evaluator: a flat, JSON-able ``{dotted name: value}`` dict. An object with a ``fingerprint()`` method
describes itself (its entries are described in turn); any other object is described by its class
and its public attributes, recursively (numbers, strings, flags and plain lists as they are, tensors
and arrays by :func:`hbni_infra.fingerprint.digest`, functions by their qualified name), so two Monte
Carlo evaluators of Dec-Tiger at horizons 3 and 4 differ in ``env.horizon``.
"""

from __future__ import annotations

import json
import types
from typing import Any

import numpy as np
import torch

from hbni_infra.fingerprint import digest

_MAX_DEPTH = 4


def describe(obj: Any) -> dict[str, Any]:
    """Flat description ``{dotted name: JSON value}`` of an evaluator (or any object), see the module doc."""
    out: dict[str, Any] = {}
    _describe(obj, "", out, set(), 0)
    return json.loads(json.dumps(out))  # as it reads back from a checkpoint


def _name(obj: Any) -> str:
    kind = obj if isinstance(obj, type) else type(obj)
    return f"{kind.__module__}.{kind.__qualname__}"


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
