"""Where numba caches the engine's compiled code, keyed by the engine's own sources.

A domain's chunk function inlines the engine's event loop and random streams, and numba's cache only
notices a change of the chunk function's own file. So the cache lives in a directory named by a digest
of the engine's sources and numba's version: a changed engine never loads a stale kernel. The base
directory is ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/hbni-pyro`` (``~/.cache/hbni-pyro``),
else, if neither is writable, the system's temporary directory.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numba


def cache_dir() -> Path:
    """This engine's numba cache directory (created if missing)."""
    h = hashlib.sha256(numba.__version__.encode())
    for source in sorted(Path(__file__).parent.glob("*.py")):
        h.update(source.name.encode() + b"\0" + source.read_bytes())
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
    raise RuntimeError("no writable directory for the engine's compiled code; set NUMBA_CACHE_DIR")


def use_cache_dir() -> Path:
    """Point numba's cache at :func:`cache_dir` (before any engine function is compiled)."""
    path = cache_dir()
    numba.config.CACHE_DIR = str(path)
    return path
