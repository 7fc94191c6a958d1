"""A run's status file, ``status.json``: running, completed or failed (with the error)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from experiments.runs.outputs import write_json

STATUS = "status.json"
STATES = ("running", "completed", "failed")


def write_status(run_dir: str | os.PathLike, state: str, error: str | None = None) -> Path:
    """Atomically record ``state`` (one of :data:`STATES`) and, for a failed run, its error."""
    if state not in STATES:
        raise ValueError(f"state: expected one of {list(STATES)}, got {state!r}")
    entry: dict[str, Any] = {"status": state}
    if error is not None:
        entry["error"] = error
    return write_json(Path(run_dir) / STATUS, entry)


def read_status(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The recorded status of a run (``None`` when the run wrote none)."""
    path = Path(run_dir) / STATUS
    if not path.is_file():
        return None
    try:
        entry = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: corrupt status file ({exc})") from None
    if not isinstance(entry, dict) or entry.get("status") not in STATES:
        raise ValueError(f"{path}: expected a status in {list(STATES)}, got {entry!r}")
    return entry
