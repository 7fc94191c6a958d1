"""Fingerprinted checkpoints: tensors + JSON state that refuse to resume any run but the one that wrote them.

A checkpoint file holds named tensors and a JSON header with its format ``version``, the writing run's
``fingerprint`` (:mod:`hbni_infra.fingerprint`; its ``problem`` entry from :mod:`decpomdp.identity`) and the
run's counters and histories. Loading checks, in this order, that the file is a ``kind`` checkpoint of
this ``version``, that its fingerprint equals this run's (else a ``ValueError`` names the first field
that differs), and then reads counters and histories
through :func:`read_count` and :func:`read_history`, which reject missing, mistyped or inconsistent
entries with a message naming the entry.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from torch import Tensor

from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.fingerprint import check_fingerprint


def save_checkpoint(
    path: str | os.PathLike,
    kind: str,
    version: int,
    fingerprint: dict[str, Any],
    tensors: dict[str, Tensor],
    state: dict[str, Any],
) -> Path:
    """Atomically write a checkpoint (``state`` must be JSON-serialisable)."""
    return save_tensors(path, kind, tensors, {"fingerprint": fingerprint, **state}, version=version)


def load_checkpoint(
    path: str | os.PathLike, kind: str, version: int, fingerprint: dict[str, Any]
) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Read a checkpoint written by :func:`save_checkpoint` for a run with this ``fingerprint``."""
    tensors, meta = load_tensors(path, kind, version=version)
    check_fingerprint(meta.get("fingerprint"), fingerprint, "checkpoint", path)
    return tensors, meta


def read_count(meta: dict[str, Any], name: str, path: str | os.PathLike, maximum: int) -> int:
    """``meta[name]`` as an int in [0, maximum], else a ``ValueError`` naming the entry."""
    value = meta.get(name)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= maximum:
        raise ValueError(f"checkpoint: {str(path)!r} has {name} = {value!r}, expected an int in [0, {maximum}]")
    return value


def read_number(meta: dict[str, Any], name: str, path: str | os.PathLike) -> float:
    """``meta[name]`` as a float (``None`` stands for -inf, "nothing yet"), else a ``ValueError``."""
    value = meta.get(name, "<missing>")
    if value is None:
        return -math.inf
    if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
        raise ValueError(f"checkpoint: {str(path)!r} has {name} = {value!r}, expected a number or null")
    return float(value)


def read_history(
    meta: dict[str, Any], keys: tuple[str, ...], length: int, path: str | os.PathLike, none: float = -math.inf
) -> dict[str, list[float]]:
    """``meta["history"]``: a dict of ``keys`` to lists of ``length`` numbers (``None`` read as ``none``)."""
    history = meta.get("history")
    if not isinstance(history, dict) or set(history) != set(keys):
        raise ValueError(
            f"checkpoint: {str(path)!r} has history = {type(history).__name__}, "
            f"expected a dict with keys {sorted(keys)}"
        )
    out = {}
    for key in keys:
        values = history[key]
        if (
            not isinstance(values, list)
            or len(values) != length
            or not all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values)
        ):
            raise ValueError(
                f"checkpoint: {str(path)!r} has history[{key!r}] inconsistent with {length} recorded iterations"
            )
        out[key] = [none if v is None else float(v) for v in values]
    return out
