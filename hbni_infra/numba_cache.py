"""Where numba caches the project's compiled code, keyed by the sources that compiled code inlines.

A compiled function inlines code of other files (a domain's chunk function the engine's event loop, and
both it and the compiled MH class move the counter-based random streams), and numba's cache only notices a
change of the function's own file. So the cache lives in a directory named by a digest of numba's version
and of every file whose code is inlined elsewhere (:data:`INLINED`): a changed engine or random stream
never loads a stale kernel. The base
directory is ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/hbni-pyro`` (``~/.cache/hbni-pyro``),
else, if neither is writable, the system's temporary directory.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numba


INLINED = ("hbni_infra/counter_random.py", "decpomdp/engine/*.py")
"""Sources (globs relative to the directory holding the project's packages) inlined into compiled code."""


def cache_dir(root: Path | None = None) -> Path:
    """The numba cache directory of the :data:`INLINED` sources under ``root`` (default: where this package lies),
    created if missing."""
    root = Path(__file__).resolve().parent.parent if root is None else root
    h = hashlib.sha256(numba.__version__.encode())
    for source in sorted(p for pattern in INLINED for p in root.glob(pattern)):
        h.update(str(source.relative_to(root)).encode() + b"\0" + source.read_bytes())
    name = f"numba-{h.hexdigest()[:16]}"
    user = os.environ.get("NUMBA_CACHE_DIR")
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    for base in ([user] if user else []) + [
        os.path.join(xdg, "hbni-pyro"),
        os.path.join(tempfile.gettempdir(), "hbni-pyro"),
    ]:
        path = Path(base) / name
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(path, os.W_OK):
            return path
    raise RuntimeError("no writable directory for numba's compiled code; set NUMBA_CACHE_DIR")


_chosen: Path | None = None


def use_cache_dir() -> Path:
    """Point numba's cache at :func:`cache_dir` (once; call it before decorating any cached function: numba reads
    the directory when a function is decorated)."""
    global _chosen
    if _chosen is None:
        _chosen = cache_dir()
        numba.config.CACHE_DIR = str(_chosen)
    return _chosen
