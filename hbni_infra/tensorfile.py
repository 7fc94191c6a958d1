"""One-file storage of fitted objects: named tensors plus JSON metadata, no pickle.

The file is a `safetensors <https://github.com/huggingface/safetensors>`_ container: a JSON
header, then raw little-endian tensor bytes. Loading parses JSON and copies bytes; nothing is
unpickled, so a foreign file cannot run code. The header's metadata holds ``kind`` (what the file
holds, e.g. ``"decpomdp.JointController"``) and ``metadata`` (JSON), whose ``version`` is the format
version of that kind: a loader names the version it reads and refuses any other, telling a file
from a newer release of the package apart. Writes are atomic (:func:`hbni_infra.files.atomic_write_bytes`).

Files written before this module existed kept the kind under ``"<package>.kind"`` (and the
metadata under ``"<package>.metadata"``); they still load.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from safetensors import SafetensorError
from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save
from torch import Tensor

from hbni_infra.files import atomic_write_bytes

_KIND_KEY = "kind"
_META_KEY = "metadata"


def save_tensors(
    path: str | os.PathLike, kind: str, tensors: dict[str, Tensor], metadata: dict[str, Any], version: int = 1
) -> Path:
    """Atomically save named ``tensors`` and JSON-serialisable ``metadata``, tagged with ``kind`` and its format
    ``version``."""
    header = {_KIND_KEY: kind, _META_KEY: json.dumps({**metadata, "version": version})}
    data = _st_save({k: v.detach().contiguous().cpu() for k, v in tensors.items()}, metadata=header)
    return atomic_write_bytes(path, data)


def load_tensors(path: str | os.PathLike, kind: str, version: int = 1) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Load a file written by :func:`save_tensors` and check that it holds a ``kind`` object of format ``version``
    (a file without one is version 1).

    Returns:
        the tensors (fresh copies, safe to modify) and the metadata.

    Raises:
        FileNotFoundError: no file at ``path``.
        IsADirectoryError: ``path`` is a directory.
        ValueError: the file is corrupt, not in this format, holds another kind of object or another format
            version (a newer one says so: the package needs an upgrade).
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path: {str(path)!r} is a directory, expected a saved {kind} file")
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    raw = path.read_bytes()
    try:
        tensors = _st_load(raw)
        found, meta_text = _kind_and_metadata(_read_header(raw))
    except (SafetensorError, ValueError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"path: {str(path)!r} is not a readable model file ({exc})") from None
    if found != kind:
        raise ValueError(f"path: {str(path)!r} holds {found or 'a foreign file'}, expected a saved {kind}")
    try:
        metadata = json.loads(meta_text)
    except (TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"path: {str(path)!r} has corrupt metadata for a saved {kind} ({exc})") from None
    if not isinstance(metadata, dict):
        raise ValueError(f"path: {str(path)!r} has corrupt metadata for a saved {kind} (not a JSON object)")
    found_version = metadata.get("version", 1)
    if found_version != version:
        newer = isinstance(found_version, int) and not isinstance(found_version, bool) and found_version > version
        raise ValueError(
            f"path: {str(path)!r} holds format version {found_version!r} of a saved {kind}; this "
            f"version of the package reads version {version}"
            + (" (the file comes from a newer release: upgrade the package)" if newer else "")
        )
    return {k: v.clone() for k, v in tensors.items()}, metadata


def _read_header(raw: bytes) -> dict[str, str]:
    if len(raw) < 8:
        raise ValueError("file too short")
    n = int.from_bytes(raw[:8], "little")
    if n <= 0 or 8 + n > len(raw):
        raise ValueError("bad header length")
    header = json.loads(raw[8 : 8 + n].decode("utf-8"))
    meta = header.get("__metadata__") if isinstance(header, dict) else None
    return meta if isinstance(meta, dict) else {}


def _kind_and_metadata(header: dict[str, str]) -> tuple[str | None, str | None]:
    """(kind, metadata JSON) of a header, also in the older ``"<package>.kind"`` layout."""
    if _KIND_KEY in header:
        return header[_KIND_KEY], header.get(_META_KEY)
    for key, value in header.items():
        if key.endswith(".kind"):
            package = key[: -len(".kind")]
            kind = value if "." in value else f"{package}.{value}"
            return kind, header.get(f"{package}.metadata")
    return None, None
