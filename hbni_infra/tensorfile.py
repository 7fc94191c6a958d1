"""One-file storage of fitted objects: named tensors plus JSON metadata, no pickle.

The file is a `safetensors <https://github.com/huggingface/safetensors>`_ container: a JSON
header, then raw little-endian tensor bytes. Loading parses JSON and copies bytes; nothing is
unpickled, so a foreign file cannot run code. The header's metadata holds ``kind`` (what the file
holds, e.g. ``"decpomdp.JointController"``) and ``metadata`` (JSON), whose ``version`` is the format
version of that kind: a loader names the version it reads and refuses any other, telling a file
from a newer release of the package apart. Writes are atomic (:func:`hbni_infra.files.atomic_write_bytes`).

Every file also carries ``digest``: a SHA-256 over its kind, its metadata text and every tensor's name,
dtype, shape and bytes (:func:`file_digest`). Loading recomputes it and refuses a file whose tensors or
metadata were changed after it was saved (an edited class list, a patched tensor), naming the file. A
file without a digest (written by a release before digests, in either header layout: ``kind`` or the
older ``"<package>.kind"``) is refused too, with the call that adds one after the user has checked it:
:func:`seal`.
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
from hbni_infra.fingerprint import digest

_KIND_KEY = "kind"
_META_KEY = "metadata"
_DIGEST_KEY = "digest"
_DIGEST_PREFIX = "sha256:"


def file_digest(kind: str, metadata_text: str, tensors: dict[str, Tensor]) -> str:
    """``"sha256:<hex>"`` over ``kind``, the metadata's JSON text and every tensor (by name: dtype, shape, bytes)."""
    parts = [kind, metadata_text]
    for name in sorted(tensors):
        parts += [name, tensors[name]]
    return _DIGEST_PREFIX + digest(*parts)


def save_tensors(
    path: str | os.PathLike, kind: str, tensors: dict[str, Tensor], metadata: dict[str, Any], version: int = 1
) -> Path:
    """Atomically save named ``tensors`` and JSON-serialisable ``metadata``, tagged with ``kind`` and its format
    ``version``."""
    return _write(
        path,
        kind,
        {k: v.detach().contiguous().cpu() for k, v in tensors.items()},
        json.dumps({**metadata, "version": version}),
    )


def _write(path: str | os.PathLike, kind: str, tensors: dict[str, Tensor], meta_text: str) -> Path:
    header = {_KIND_KEY: kind, _META_KEY: meta_text, _DIGEST_KEY: file_digest(kind, meta_text, tensors)}
    return atomic_write_bytes(path, _st_save(tensors, metadata=header))


def load_tensors(path: str | os.PathLike, kind: str, version: int = 1) -> tuple[dict[str, Tensor], dict[str, Any]]:
    """Load a file written by :func:`save_tensors` and check that it holds a ``kind`` object of format ``version``
    (a file without one is version 1) whose tensors and metadata match its digest.

    Returns:
        the tensors (fresh copies, safe to modify) and the metadata.

    Raises:
        FileNotFoundError: no file at ``path``.
        IsADirectoryError: ``path`` is a directory.
        ValueError: the file is corrupt, not in this format, holds another kind of object or another format
            version (a newer one says so: the package needs an upgrade), has no digest, or its tensors or
            metadata differ from what its digest records (edited after it was saved).
    """
    path, tensors, meta_text, recorded = _read(path, kind)
    metadata = _metadata(path, kind, meta_text)
    found_version = metadata.get("version", 1)
    if found_version != version:
        newer = isinstance(found_version, int) and not isinstance(found_version, bool) and found_version > version
        raise ValueError(
            f"path: {str(path)!r} holds format version {found_version!r} of a saved {kind}; this "
            f"version of the package reads version {version}"
            + (" (the file comes from a newer release: upgrade the package)" if newer else "")
        )
    if recorded is None:
        raise ValueError(
            f"path: {str(path)!r} has no digest (it was written by a release before digests); once you have "
            f"checked that it is what it says, add one with hbni_infra.tensorfile.seal({str(path)!r}, {kind!r})"
        )
    if recorded != file_digest(kind, meta_text, tensors):
        raise ValueError(
            f"path: {str(path)!r} does not match its digest: its tensors or metadata were changed after it was saved; "
            "refusing it (save the object again from its source)"
        )
    return {k: v.clone() for k, v in tensors.items()}, metadata


def seal(path: str | os.PathLike, kind: str) -> Path:
    """Give the ``kind`` file at ``path`` a digest of its present content (in the current header layout).

    For a file written before digests, or one edited on purpose, once its content has been checked: the
    file is rewritten atomically with the same tensors and metadata, and loads from then on.

    Raises:
        FileNotFoundError, IsADirectoryError, ValueError: as :func:`load_tensors` for a missing, corrupt or
            foreign file.
    """
    path, tensors, meta_text, _ = _read(path, kind)
    _metadata(path, kind, meta_text)
    return _write(path, kind, tensors, meta_text)


def _read(path: str | os.PathLike, kind: str) -> tuple[Path, dict[str, Tensor], str, str | None]:
    """The path, tensors, metadata text and recorded digest (``None``: none) of a ``kind`` file."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path: {str(path)!r} is a directory, expected a saved {kind} file")
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    raw = path.read_bytes()
    try:
        tensors = _st_load(raw)
        header = _read_header(raw)
        found, meta_text = _kind_and_metadata(header)
    except (SafetensorError, ValueError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"path: {str(path)!r} is not a readable model file ({exc})") from None
    if found != kind:
        raise ValueError(f"path: {str(path)!r} holds {found or 'a foreign file'}, expected a saved {kind}")
    if not isinstance(meta_text, str):
        raise ValueError(f"path: {str(path)!r} has corrupt metadata for a saved {kind} (none recorded)")
    return path, tensors, meta_text, header.get(_DIGEST_KEY)


def _metadata(path: Path, kind: str, meta_text: str) -> dict[str, Any]:
    try:
        metadata = json.loads(meta_text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"path: {str(path)!r} has corrupt metadata for a saved {kind} ({exc})") from None
    if not isinstance(metadata, dict):
        raise ValueError(f"path: {str(path)!r} has corrupt metadata for a saved {kind} (not a JSON object)")
    return metadata


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
