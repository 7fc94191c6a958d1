"""A fingerprinted on-disk cache of tensors that take long to compute (rendered and classified frames).

An entry is one tensor file named by its key and the digest of its fingerprint (everything that
determines its content: seeds, sizes, classes, imaging conditions, classifier settings), and it
stores that fingerprint. Other inputs give another file; a file whose stored fingerprint differs
from the run's (corrupt, or edited by hand) is refused, naming the first field that differs.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from torch import Tensor

from infra.fingerprint import check_fingerprint, digest
from infra.tensorfile import load_tensors, save_tensors

_KIND = "experiments.TensorCache"


def cached(
    cache_dir: str | os.PathLike | None, key: str, fingerprint: dict[str, Any], compute: Callable[[], dict[str, Tensor]]
) -> tuple[dict[str, Tensor], Path | None, bool]:
    """Tensors for ``fingerprint``: from ``cache_dir`` if a run with the same inputs stored them, else
    from ``compute()`` (then stored). ``cache_dir=None`` always computes.

    Returns:
        the tensors, the cache file (``None`` without a cache) and whether they came from it.
    """
    if cache_dir is None:
        return compute(), None, False
    path = Path(cache_dir) / f"{key}-{digest(fingerprint)[:16]}.safetensors"
    if path.is_file():
        tensors, meta = load_tensors(path, _KIND)
        check_fingerprint(meta.get("fingerprint"), fingerprint, "cache", path)
        return tensors, path, True
    tensors = compute()
    save_tensors(path, _KIND, tensors, {"fingerprint": fingerprint})
    return tensors, path, False
