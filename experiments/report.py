"""Markdown reports: one per run (written by the experiment) and one per multirun comparing its jobs.

:class:`MultirunReport` is a Hydra callback (registered in ``conf/config.yaml``): when a ``-m``
sweep ends it reads every job's ``.hydra/overrides.yaml`` and ``metrics.json`` and writes
``<sweep dir>/report.md`` with one row per job.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from infra.files import atomic_write_bytes


def write_report(path: str | os.PathLike, text: str) -> Path:
    """Atomically write a markdown report."""
    return atomic_write_bytes(path, text.encode())


def _scalars(metrics: dict[str, Any], prefix: str = "", depth: int = 2) -> dict[str, Any]:
    """Flatten numbers and booleans of ``metrics`` up to ``depth`` levels: ``{"a.b": 1.0}``."""
    out: dict[str, Any] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, bool) or isinstance(value, (int, float)):
            out[name] = value
        elif isinstance(value, dict) and depth > 1:
            out.update(_scalars(value, f"{name}.", depth - 1))
    return out


def _job_columns(metrics: dict[str, Any]) -> dict[str, str]:
    """The columns a job contributes: per-variant values for the mission, top-level scalars otherwise."""
    if "variants" in metrics:
        cols = {f"{k} value": f"{v['value']:.3f} ± {v['stderr']:.3f}" for k, v in metrics["variants"].items()}
        cols.update({f"{k} wrong rate": f"{v['wrong_rate']:.3f}" for k, v in metrics["variants"].items()})
        return cols
    return {k: f"{v:.4g}" if isinstance(v, float) else str(v) for k, v in _scalars(metrics).items()}


def multirun_report(sweep_dir: str | os.PathLike) -> str:
    """Markdown comparing the finished jobs of a sweep directory (jobs without metrics are listed as failed)."""
    sweep_dir = Path(sweep_dir)
    rows: list[tuple[str, str, dict[str, str]]] = []
    for job in sorted((p for p in sweep_dir.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name)):
        overrides_file = job / ".hydra" / "overrides.yaml"
        overrides = " ".join(OmegaConf.load(overrides_file)) if overrides_file.is_file() else "?"
        metrics_file = job / "metrics.json"
        cols = _job_columns(json.loads(metrics_file.read_text())) if metrics_file.is_file() else {"status": "failed"}
        rows.append((job.name, overrides, cols))
    columns = list(dict.fromkeys(c for _, _, cols in rows for c in cols))
    lines = [f"# Sweep report: {sweep_dir}", "", f"{len(rows)} jobs.", "",
             "| job | overrides | " + " | ".join(columns) + " |", "|---" * (len(columns) + 2) + "|"]
    for name, overrides, cols in rows:
        lines.append(f"| [{name}]({name}/) | `{overrides}` | " + " | ".join(cols.get(c, "") for c in columns) + " |")
    return "\n".join(lines) + "\n"


class MultirunReport(Callback):
    """Hydra callback: write ``report.md`` into the sweep directory when a multirun ends."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if sweep_dir.is_dir():
            write_report(sweep_dir / "report.md", multirun_report(sweep_dir))
