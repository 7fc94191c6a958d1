"""A run's ``report.md`` when its study writes none: what ran, its headline metrics, its figures and saved models.

Studies with a report of their own (the mission, the planners, the noise-model comparison) write it; for every
other experiment :func:`write_run_report` writes this summary, so that every run folder has a ``report.md`` to open
first.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from experiments.reports.sweep_report import headline_values
from experiments.runs.artifacts import MANIFEST
from experiments.runs.outputs import write_report

REPORT = "report.md"


def write_run_report(run_dir: Path, settings: Any, metrics: dict[str, Any]) -> Path | None:
    """Write ``run_dir/report.md`` (:func:`run_report`) unless the study wrote one; returns its path when written."""
    path = run_dir / REPORT
    if path.exists():
        return None
    return write_report(path, run_report(run_dir, settings, metrics))


def run_report(run_dir: Path, settings: Any, metrics: dict[str, Any]) -> str:
    """Markdown for the run of ``settings`` (its typed settings: ``name``, ``seed``, ``headline``) in ``run_dir``: the
    experiment, seed and overrides, the headline metrics (``settings.headline``), the figures (shown)
    and the saved models (with the call that loads them)."""
    lines = [f"# {settings.name}: run report", "", f"Seed {settings.seed}. Every number is in `metrics.json`."]
    overrides_file = run_dir / ".hydra" / "overrides.yaml"
    overrides = yaml.safe_load(overrides_file.read_text()) if overrides_file.is_file() else None
    if overrides:
        lines += ["", "Overrides: " + " ".join(f"`{o}`" for o in overrides)]
    values = headline_values(metrics, list(settings.headline))
    if values:
        lines += ["", "## Headline", "", "| metric | value |", "|---|---|"]
        lines += [f"| {name} | {value} |" for name, value in values.items()]
    figures = sorted(p.name for p in run_dir.glob("*.png"))
    if figures:
        lines += ["", "## Figures", ""] + [f"![{name}]({name})" for name in figures]
    manifest = run_dir / MANIFEST
    artifacts = json.loads(manifest.read_text()) if manifest.is_file() else {}
    if artifacts:
        lines += ["", "## Saved models", "", "| name | kind | file |", "|---|---|---|"]
        lines += [f"| {name} | {entry['kind']} | `{entry['path']}` |" for name, entry in artifacts.items()]
        first = next(iter(artifacts))
        lines += ["", f'Load them with `run = experiments.load_run("{run_dir}")`, then e.g. `run.{first}`.']
    return "\n".join(lines) + "\n"
