"""The entry point under signals and errors: SIGTERM and SIGHUP mark the run failed and end its background
workers; a config that fails its check prints one line and leaves no run folder; an error inside the run prints one
line, its traceback in run.log."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from experiment_runs import run_experiment

from experiments.runs.processes import children, start_time

from mission_tiny import TINY_MISSION

pytestmark = pytest.mark.usefixtures("signals_delivered")  # a test started in the background too
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_marks_the_run_failed_and_stops_its_workers(tmp_path, signum):
    # the bank is built by one background process from a fresh cache folder while the mission goes on
    cmd = [
        sys.executable,
        "-m",
        "experiments.run",
        "experiment=mission",
        *TINY_MISSION,
        f"hydra.run.dir={tmp_path / 'run'}",
        "perception=hbni",
        "mission.bank.workers=1",
        "mission.bank.sequences=60",
        f"mission.bank.cache_dir={tmp_path / 'cache'}",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    status = tmp_path / "run" / "status.json"
    deadline = time.time() + 120
    workers: set[int] = set()
    while time.time() < deadline and not workers:  # wait for the bank's worker to start
        workers = (
            {c for c in children(proc.pid) if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text()}
            if start_time(proc.pid) is not None
            else set()
        )
        time.sleep(0.2)
    assert workers and json.loads(status.read_text())["status"] == "running"
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode != 0
    entry = json.loads(status.read_text())
    assert entry["status"] == "failed" and f"stopped by {signal.Signals(signum).name}" in entry["error"], stderr
    time.sleep(2)
    assert not [w for w in workers if start_time(w) is not None], "a bank worker outlived the run"
    assert not list((tmp_path / "cache").glob("*.lock"))  # the bank's lock released


def test_a_config_error_is_one_line_and_leaves_no_run_folder(tmp_path):
    run_dir = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    proc = run_experiment(
        ["experiment=mission", f"hydra.run.dir={run_dir}", "mission.threshold=1.5"], ROOT, env=env, check=False
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "config error: mission.threshold: expected a finite number in (0, 1], got 1.5"
    assert not run_dir.exists()


def test_a_planner_setting_the_planner_ignores_is_refused_at_the_start(tmp_path):
    proc = run_experiment(
        ["experiment=mission", f"hydra.run.dir={tmp_path / 'run'}", "warm_planner.ce_alpha=0.3"], ROOT, check=False
    )
    assert (
        proc.returncode == 2 and "config error: warm_planner.ce_alpha: experiment mission never reads it" in proc.stderr
    )
    assert not (tmp_path / "run").exists()


def test_a_runs_own_error_is_one_line_and_its_traceback_goes_to_run_log(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "0.png"), np.zeros((32, 32, 3), np.uint8))
    run_dir = tmp_path / "run"
    args = ["experiment=stream", f"stream.source={frames}", f"hydra.run.dir={run_dir}", "progress=false"]
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"} | {"HBNI_PYRO_ROOT": str(tmp_path)}
    proc = run_experiment(args, ROOT, env=env, check=False)  # no mission run under the root to stream with
    assert proc.returncode == 1 and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("error: experiment stream failed after ") and "FileNotFoundError: stream.run" in (
        proc.stderr
    )
    assert f"traceback in {run_dir / 'run.log'}; HYDRA_FULL_ERROR=1 prints it" in proc.stderr
    assert "Traceback (most recent call last)" in (run_dir / "run.log").read_text()
    assert json.loads((run_dir / "status.json").read_text())["status"] == "failed"
    full = run_experiment(
        [*args[:-2], f"hydra.run.dir={tmp_path / 'again'}"], ROOT, env={**env, "HYDRA_FULL_ERROR": "1"}, check=False
    )
    assert full.returncode == 1 and "Traceback (most recent call last)" in full.stderr
