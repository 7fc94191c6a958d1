"""One-file storage for fitted objects: tensors plus JSON metadata, no pickle.

The file is a `safetensors <https://github.com/huggingface/safetensors>`_ container: a
JSON header, then raw little-endian tensor bytes. Loading parses JSON and copies bytes;
nothing is unpickled, so a foreign file cannot run code. Writes go to a temporary file
in the target directory and are renamed into place, so a crash never leaves half a file.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from safetensors import SafetensorError
from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save
from torch import Tensor

_KIND_KEY = "hbni_pyro.kind"
_META_KEY = "hbni_pyro.metadata"


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def save_tensors(path: str | os.PathLike, kind: str, tensors: dict[str, Tensor], metadata: dict[str, Any]) -> Path:
    """Atomically save named tensors and JSON-serialisable ``metadata`` tagged with ``kind``."""
    header = {_KIND_KEY: kind, _META_KEY: json.dumps(metadata)}
    data = _st_save({k: v.detach().contiguous().cpu() for k, v in tensors.items()}, metadata=header)
    return atomic_write_bytes(path, data)


def load_tensors(path: str | os.PathLike, kind: str) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Load a file written by :func:`save_tensors` and check it holds a ``kind`` object.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is corrupt, not in this format, or holds another kind of object.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    raw = path.read_bytes()
    try:
        tensors = _st_load(raw)
        header = _read_header(raw)
    except (SafetensorError, ValueError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable hbni_pyro file ({exc})") from None
    found = header.get(_KIND_KEY)
    if found != kind:
        raise ValueError(f"{path}: expected a saved {kind}, found {found or 'a foreign file'}")
    try:
        metadata = json.loads(header[_META_KEY])
    except (KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: corrupt metadata in saved {kind} ({exc})") from None
    return {k: v.clone() for k, v in tensors.items()}, metadata


def _read_header(raw: bytes) -> dict[str, str]:
    if len(raw) < 8:
        raise ValueError("file too short")
    n = int.from_bytes(raw[:8], "little")
    if n <= 0 or 8 + n > len(raw):
        raise ValueError("bad header length")
    return json.loads(raw[8 : 8 + n].decode("utf-8")).get("__metadata__", {}) or {}

