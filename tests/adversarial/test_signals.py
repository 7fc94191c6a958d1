"""The signal boundary: SIGTERM or SIGINT to a ``-m`` sweep's parent ends the whole process tree, marks every job
failed (those that never started too) and writes the sweep report; a single run marks itself failed. Real
subprocesses of the cheapest experiment (``hbni_toy``), its fit made long so that the signal finds it running."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# a fit that runs for minutes: the signal always comes while the jobs run
SLOW = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=1000000", "hbni.fit.warmup_steps=10", "progress=false"]
TIMEOUT_S = 240


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _tree(pid: int) -> set[int]:
    """Every process below ``pid`` (Linux /proc)."""
    out: set[int] = set()
    todo = _children(pid)
    while todo:
        child = todo.pop()
        if child not in out:
            out.add(child)
            todo += _children(child)
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, ProcessLookupError):
        return False


def _status(folder: Path) -> dict | None:
    try:
        return json.loads((folder / "status.json").read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _wait_for(predicate, proc: subprocess.Popen, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        if proc.poll() is not None:
            raise AssertionError(f"the process ended before {what}: {proc.stderr.read()}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no {what} within {TIMEOUT_S} s")
        time.sleep(0.2)


def _stop_and_collect(proc: subprocess.Popen, signum: int) -> tuple[set[int], str]:
    """Send ``signum`` to ``proc``; the processes of its tree at that moment and its stderr once it has ended."""
    tree = _tree(proc.pid)
    proc.send_signal(signum)
    try:
        _, stderr = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"the parent outlived {signal.Signals(signum).name} by {TIMEOUT_S} s") from None
    deadline = time.monotonic() + 30
    while [p for p in tree if _alive(p)] and time.monotonic() < deadline:
        time.sleep(0.2)
    return tree, stderr


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_to_a_sweep_ends_every_job_marks_them_failed_and_writes_the_report(tmp_path, signum):
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "experiments.run", "-m", "experiment=hbni_toy", "seed=0,1,2", *SLOW]
    proc = subprocess.Popen(
        [*cmd, f"hydra.sweep.dir={sweep}", "hydra.launcher.n_jobs=2"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    running = lambda: all((_status(sweep / str(k)) or {}).get("status") == "running" for k in (0, 1))  # noqa: E731
    _wait_for(running, proc, "two running jobs")
    tree, stderr = _stop_and_collect(proc, signum)
    name = signal.Signals(signum).name
    assert proc.returncode == -signum, stderr  # the parent dies by the signal it got
    assert len(tree) >= 2 and not [p for p in tree if _alive(p)], "a process of the sweep outlived it"
    statuses = {k: _status(sweep / str(k)) for k in range(3)}
    assert all(s is not None and s["status"] == "failed" for s in statuses.values()), statuses
    # the parent passes any of its signals on to its workers as SIGTERM, and a running job says so; one the
    # signal reaches before its handler is set is marked by the parent, naming the sweep's signal
    for k in (0, 1):
        assert statuses[k]["error"] in ("Stopped: stopped by SIGTERM", f"stopped by {name}: the sweep was stopped"), (
            statuses
        )
    assert statuses[2]["error"] == f"not started: the sweep was stopped by {name}"
    report = (sweep / "report.md").read_text()
    assert "3 jobs, 0 completed." in report and report.count("| failed |") == 3, report
    assert f"sweep stopped by {name}" in stderr


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_to_a_single_run_marks_it_failed(tmp_path, signum):
    run_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", "experiment=hbni_toy", *SLOW, f"hydra.run.dir={run_dir}"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(lambda: (_status(run_dir) or {}).get("status") == "running", proc, "a running job")
    tree, stderr = _stop_and_collect(proc, signum)
    assert proc.returncode != 0
    assert not [p for p in tree if _alive(p)], "a process of the run outlived it"
    entry = _status(run_dir)
    name = signal.Signals(signum).name
    assert entry == {"status": "failed", "error": f"Stopped: stopped by {name}"}, (entry, stderr)
    line = stderr.strip().splitlines()[-1]  # one line: where the run was marked failed, no traceback
    assert proc.returncode == -signum and "Traceback" not in stderr, stderr
    assert line.startswith(f"experiment hbni_toy stopped by {name} after") and line.endswith(str(run_dir)), stderr
