"""Markdown reports: one per run (written by the experiment) and one per multirun comparing its jobs.

:class:`MultirunReport` is a Hydra callback (registered in ``conf/config.yaml``). It rewrites
``<sweep dir>/report.md`` whenever a job of a ``-m`` sweep ends, and once more when the sweep
ends: one row per job, the swept keys as columns, then the experiment's headline metrics (the
``headline`` list of its config: dotted paths into ``metrics.json``, ``*`` matching any key).
Failed jobs are listed with their error. Writing at each job's end means the report exists even
when a failing job stops the sweep; a lock file serialises the jobs' rewrites.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path
from typing import Any

import yaml
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from experiments.runs.outputs import write_report
from experiments.runs.status import read_status


def headline_values(metrics: dict[str, Any], paths: list[str]) -> dict[str, str]:
    """Column name -> formatted value for each headline path (``*`` matches every key at its level).

    A ``{"value", "stderr", ...}`` entry is shown as ``value ± stderr``; another dict gives one
    column per scalar entry; a list of numbers is shown whole.
    """
    out: dict[str, str] = {}
    for path in paths:
        for name, value in _resolve(metrics, path.split(".")):
            if isinstance(value, dict) and not {"value", "stderr"} <= set(value):
                out.update({f"{name}.{k}": _format(v) for k, v in value.items() if not isinstance(v, (dict, list))})
            else:
                out[name] = _format(value)
    return out


def _resolve(node: Any, parts: list[str], prefix: str = "") -> list[tuple[str, Any]]:
    if not parts:
        return [(prefix, node)]
    if not isinstance(node, dict):
        return []
    head, rest = parts[0], parts[1:]
    keys = list(node) if head == "*" else [head] if head in node else []
    return [item for k in keys for item in _resolve(node[k], rest, f"{prefix}.{k}" if prefix else k)]


def _format(value: Any) -> str:
    if isinstance(value, dict):
        return f"{value['value']:.4g} ± {value['stderr']:.2g}"
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list) and all(isinstance(v, (int, float)) for v in value):
        return "[" + ", ".join(f"{v:.3g}" for v in value) + "]"
    return str(value)


def _job(job: Path) -> dict[str, Any]:
    """Overrides, status and headline values of one job directory."""
    overrides_file = job / ".hydra" / "overrides.yaml"
    overrides = [str(o) for o in yaml.safe_load(overrides_file.read_text()) or []] if overrides_file.is_file() else []
    config_file = job / ".hydra" / "config.yaml"
    headline = list(OmegaConf.load(config_file).get("headline", [])) if config_file.is_file() else []
    status = read_status(job) or {"status": "no status (running, or stopped before it started)"}
    metrics_file = job / "metrics.json"
    values = headline_values(json.loads(metrics_file.read_text()), headline) if metrics_file.is_file() else {}
    return {
        "name": job.name,
        "overrides": dict(o.split("=", 1) for o in overrides if "=" in o),
        "status": status,
        "values": values,
    }


def multirun_report(sweep_dir: str | os.PathLike) -> str:
    """Markdown comparing the jobs of a sweep directory."""
    sweep_dir = Path(sweep_dir)
    jobs = [
        _job(p)
        for p in sorted((p for p in sweep_dir.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name))
    ]
    keys = list(dict.fromkeys(k for j in jobs for k in j["overrides"]))
    swept = [k for k in keys if len({j["overrides"].get(k) for j in jobs}) > 1]
    common = [f"{k}={jobs[0]['overrides'][k]}" for k in keys if k not in swept and k in jobs[0]["overrides"]]
    metrics = list(dict.fromkeys(c for j in jobs for c in j["values"]))
    done = sum(j["status"]["status"] == "completed" for j in jobs)
    lines = [f"# Sweep report: {sweep_dir}", "", f"{len(jobs)} jobs, {done} completed.", ""]
    if common:
        lines += ["Every job: " + " ".join(f"`{c}`" for c in common), ""]
    lines += ["| job | status | " + " | ".join(swept + metrics) + " |", "|---" * (len(swept) + len(metrics) + 2) + "|"]
    for j in jobs:
        cells = [j["overrides"].get(k, "") for k in swept] + [j["values"].get(c, "") for c in metrics]
        lines.append(f"| [{j['name']}]({j['name']}/) | {j['status']['status']} | " + " | ".join(cells) + " |")
    failed = [j for j in jobs if j["status"]["status"] == "failed"]
    if failed:
        lines += ["", "## Failed jobs", ""]
        for j in failed:
            where = " ".join(f"{k}={j['overrides'][k]}" for k in swept if k in j["overrides"])
            lines.append(f"- job {j['name']} (`{where}`): {j['status'].get('error', 'no error recorded')}")
    return "\n".join(lines) + "\n"


def update_sweep_report(sweep_dir: str | os.PathLike) -> Path:
    """Rewrite ``<sweep_dir>/report.md`` under an exclusive lock (jobs of a sweep end concurrently)."""
    sweep_dir = Path(sweep_dir)
    with open(sweep_dir / ".report.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return write_report(sweep_dir / "report.md", multirun_report(sweep_dir))
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


class MultirunReport(Callback):
    """Hydra callback: keep ``report.md`` of a ``-m`` sweep up to date as its jobs end."""

    def on_job_end(self, config: DictConfig, job_return: Any = None, **kwargs: Any) -> None:
        if config.hydra.mode == RunMode.MULTIRUN:
            sweep_dir = Path(config.hydra.sweep.dir)
            if sweep_dir.is_dir():
                update_sweep_report(sweep_dir)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if sweep_dir.is_dir():
            update_sweep_report(sweep_dir)
