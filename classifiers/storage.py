"""Safe model files: named tensors plus JSON metadata in one safetensors file, no pickle.

Writes go through a temporary file in the target directory and ``os.replace``, so a crash
never leaves half a file. A corrupt or foreign file raises ``ValueError``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save
from torch import Tensor

__all__ = ["atomic_write_bytes", "load_tensors", "save_tensors"]

_KIND_KEY = "classifiers.kind"
_META_KEY = "classifiers.metadata"


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same directory and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def save_tensors(path: str | os.PathLike, kind: str, tensors: dict[str, Tensor], metadata: dict[str, Any]) -> Path:
    """Atomically save ``tensors`` and JSON-serialisable ``metadata``, tagged with ``kind``."""
    header = {_KIND_KEY: kind, _META_KEY: json.dumps(metadata)}
    return atomic_write_bytes(path, _st_save({k: v.detach().contiguous().cpu() for k, v in tensors.items()}, header))


def load_tensors(path: str | os.PathLike, kind: str) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Load a file written by :func:`save_tensors` holding a ``kind`` object.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: corrupt file, not this format, or another kind of object.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    data = path.read_bytes()
    try:
        tensors = _st_load(data)
        header_len = int.from_bytes(data[:8], "little")
        header = json.loads(data[8 : 8 + header_len]).get("__metadata__") or {}
    except Exception as exc:
        raise ValueError(f"path: {str(path)!r} is not a valid model file ({exc})") from exc
    if header.get(_KIND_KEY) != kind:
        raise ValueError(f"path: {str(path)!r} holds {header.get(_KIND_KEY)!r}, expected a {kind!r} file")
    try:
        metadata = json.loads(header[_META_KEY])
    except (KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f"path: {str(path)!r} has corrupt metadata ({exc})") from exc
    return tensors, metadata
