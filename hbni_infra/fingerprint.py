"""What produced a checkpoint or a cache, and the check that refuses anything else.

A fingerprint is a plain JSON-able dict (problem identity, settings, seed, sizes, ...). A
checkpoint or cache stores the fingerprint of the run that wrote it; a run that wants to resume
or reuse it calls :func:`check_fingerprint` with its own, which raises a ``ValueError`` naming the
first field that differs. :func:`digest` turns anything hashable here (JSON values, tensors,
arrays, bytes) into a short stable hex string, for identities too big to store whole (a problem's
tables, a warm-start controller).
"""

from __future__ import annotations

import hashlib
import json
import os
from typing import Any

import numpy as np
import torch


def digest(*parts: Any) -> str:
    """SHA-256 (hex) of ``parts``: JSON-able values, torch tensors, numpy arrays or bytes."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, torch.Tensor):
            part = part.detach().cpu().contiguous()
            h.update(f"tensor:{part.dtype}:{tuple(part.shape)}:".encode())
            if part.numel():  # the bytes in place (a 0-d tensor as one element), no copy
                h.update(part.reshape(-1).view(torch.uint8).numpy())
        elif isinstance(part, np.ndarray):
            part = np.ascontiguousarray(part)
            h.update(f"array:{part.dtype}:{part.shape}:".encode())
            h.update(part.tobytes())
        elif isinstance(part, (bytes, bytearray)):
            h.update(b"bytes:" + bytes(part))
        else:
            h.update(b"json:" + json.dumps(part, sort_keys=True, default=str).encode())
        h.update(b"|")
    return h.hexdigest()


def check_fingerprint(
    recorded: Any, expected: dict[str, Any], what: str, path: str | os.PathLike | None = None
) -> None:
    """Raise ``ValueError`` unless ``recorded`` equals ``expected``, naming the first differing field.

    Args:
        recorded: the fingerprint stored in the checkpoint or cache (anything read from its file).
        expected: this run's fingerprint.
        what: what is being checked, e.g. ``"checkpoint"`` (starts the message).
        path: the file, for the message.
    """
    where = f" {str(path)!r}" if path is not None else ""
    if not isinstance(recorded, dict):
        raise ValueError(f"{what}{where} records no fingerprint of the run that wrote it; refusing to reuse it")
    field = _first_difference(recorded, expected)
    if field is not None:
        name, old, new = field
        raise ValueError(
            f"{what}{where} was written by another run: {name} was {old!r} there, is {new!r} here; "
            f"refusing to reuse it (delete it or point this run elsewhere)"
        )


_MISSING = "<missing>"


def _first_difference(recorded: Any, expected: Any, prefix: str = "") -> tuple[str, Any, Any] | None:
    if isinstance(recorded, dict) and isinstance(expected, dict):
        for key in sorted(set(recorded) | set(expected), key=str):
            name = f"{prefix}.{key}" if prefix else str(key)
            diff = _first_difference(recorded.get(key, _MISSING), expected.get(key, _MISSING), name)
            if diff is not None:
                return diff
        return None
    if _normalise(recorded) != _normalise(expected):
        return prefix or "fingerprint", recorded, expected
    return None


def _normalise(value: Any) -> Any:
    """JSON round trip, so tuples compare equal to lists and ints to their JSON form."""
    return json.loads(json.dumps(value, sort_keys=True, default=str))
