"""Sweeps on a real Slurm cluster: a single-node cluster on this machine (``scripts/slurm_cluster.sh``: Debian's
``slurm-wlm`` and ``munge``, daemons on localhost) runs a two-job ``hbni_toy`` sweep through ``hydra/launcher=slurm``;
SIGTERM to a second sweep's parent cancels its jobs (``squeue`` empties) and the report marks them failed. Skipped,
with the reason, where the cluster cannot start (not root, no apt-get)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAUNCHER = [
    "hydra/launcher=slurm",
    "hydra.launcher.cpus_per_task=1",  # both jobs at once on a 2-core node
    "hydra.launcher.mem_gb=2",
    "hydra.launcher.timeout_min=15",
]
QUICK = ["hbni.fit.num_samples=200", "hbni.fit.warmup_steps=100", "progress=false"]
SLOW = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=1000000", "hbni.fit.warmup_steps=10", "progress=false"]
TIMEOUT_S = 300


@pytest.fixture(scope="module")
def slurm() -> None:
    """A running single-node cluster, or a skip that says why there is none."""
    if os.geteuid() != 0:
        pytest.skip("a Slurm cluster needs root to start (scripts/slurm_cluster.sh installs and starts its daemons)")
    script = ROOT / "scripts" / "slurm_cluster.sh"
    done = subprocess.run([str(script), "start"], capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        pytest.skip(f"no Slurm cluster: scripts/slurm_cluster.sh exited {done.returncode}: {done.stderr.strip()}")


def _sweep(folder: Path, *overrides: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "experiments.run",
        "-m",
        "experiment=hbni_toy",
        *overrides,
        *LAUNCHER,
        f"hydra.sweep.dir={folder}",
    ]


def _status(folder: Path) -> dict:
    try:
        return json.loads((folder / "status.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _tasks(sweep: Path) -> set[str]:
    """The Slurm array tasks (``<job id>_<index>``) of a sweep: submitit names its job folders by them."""
    return {p.name for p in (sweep / ".submitit").glob("*_*") if p.is_dir() and p.name[:1].isdigit()}


def _queued(tasks: set[str]) -> set[str]:
    """Those of the array jobs of ``tasks`` that ``squeue`` still lists (running, pending or ending)."""
    out = subprocess.run(["squeue", "-h", "-o", "%i"], capture_output=True, text=True, check=True, timeout=30).stdout
    return {line.split("_")[0] for line in out.split()} & {task.split("_")[0] for task in tasks}


@pytest.mark.slow
def test_a_two_job_sweep_runs_on_slurm_and_a_sigterm_cancels_the_next(slurm, tmp_path):
    done = tmp_path / "done"
    subprocess.run(_sweep(done, "seed=0,1", *QUICK), cwd=ROOT, check=True, capture_output=True, timeout=TIMEOUT_S)
    assert len(_tasks(done)) == 2  # two Slurm array tasks ran them
    for job in ("0", "1"):
        assert _status(done / job).get("status") == "completed", _status(done / job)
        assert (done / job / "metrics.json").is_file()
    report = (done / "report.md").read_text()
    assert "2 jobs, 2 completed." in report
    assert [line.split(" | ")[1] for line in report.splitlines() if line.startswith("| [")] == ["completed"] * 2

    stopped = tmp_path / "stopped"
    proc = subprocess.Popen(
        _sweep(stopped, "seed=0,1", *SLOW), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + TIMEOUT_S
    while not all(_status(stopped / job).get("status") == "running" for job in ("0", "1")):
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline, "the second sweep's jobs never ran"
        time.sleep(0.5)
    ids = _tasks(stopped)
    assert len(ids) == 2 and _queued(ids)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == -signal.SIGTERM, stderr
    deadline = time.monotonic() + 60
    while _queued(ids) and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not _queued(ids), f"jobs {sorted(_queued(ids))} outlived their sweep in squeue"
    for job in ("0", "1"):
        status = _status(stopped / job)
        assert status.get("status") == "failed" and "SIGTERM" in status.get("error", ""), status
    report = (stopped / "report.md").read_text()
    assert [line.split(" | ")[1] for line in report.splitlines() if line.startswith("| [")] == ["failed"] * 2
