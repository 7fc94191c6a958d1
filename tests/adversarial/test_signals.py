"""The signal boundary: SIGTERM or SIGINT to a ``-m`` sweep's parent ends the whole process tree, marks every job
failed (those that never started too) and writes the sweep report; a single run marks itself failed, also when
the signal lands while numba compiles (where the handler's exception is lost) or during the imports; code that
swallows the stop is ended by the watchdog, or at once by a second signal. Real subprocesses of the cheapest
experiment (``hbni_toy``), its fit made long so that the signal finds it running."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from experiments.runs.processes import descendants, start_time
from experiments.runs.signals import GRACE_S

pytestmark = pytest.mark.usefixtures("signals_delivered")  # a test started in the background too
ROOT = Path(__file__).resolve().parents[2]
# a fit that runs for minutes: the signal always comes while the jobs run
SLOW = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=1000000", "hbni.fit.warmup_steps=10", "progress=false"]
TIMEOUT_S = 240


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
    tree = set(descendants(proc.pid))
    proc.send_signal(signum)
    try:
        _, stderr = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"the parent outlived {signal.Signals(signum).name} by {TIMEOUT_S} s") from None
    deadline = time.monotonic() + 30
    while [p for p in tree if start_time(p) is not None] and time.monotonic() < deadline:
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
    assert len(tree) >= 2 and not [p for p in tree if start_time(p) is not None], "a process of the sweep outlived it"
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
    assert not [p for p in tree if start_time(p) is not None], "a process of the run outlived it"
    entry = _status(run_dir)
    name = signal.Signals(signum).name
    assert entry == {"status": "failed", "error": f"Stopped: stopped by {name}"}, (entry, stderr)
    line = stderr.strip().splitlines()[-1]  # one line: where the run was marked failed, no traceback
    assert proc.returncode == -signum and "Traceback" not in stderr, stderr
    assert line.startswith(f"experiment hbni_toy stopped by {name} after") and line.endswith(str(run_dir)), stderr


def _caught(pid: int, signum: int) -> bool:
    """Whether process ``pid`` has a handler for ``signum`` (``SigCgt`` in /proc)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next((line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), "0")
    return bool(int(caught, 16) >> (signum - 1) & 1)


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT], ids=["SIGINT"])  # SIGTERM and SIGHUP: scripts/signal_stress.py
def test_a_signal_while_numba_compiles_ends_the_run(tmp_path, signum):
    # the signal arrives inside the callback numba's compiler makes into Python, whose exception C code ignores:
    # the run must still end within seconds and be marked failed (an empty numba cache: the run compiles)
    run_dir = tmp_path / "run"
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
        "STOP_SIGNAL": signal.Signals(signum).name,
        "STOP_RUN_DIR": str(run_dir),
    }
    driver = Path(__file__).with_name("stop_while_compiling.py")
    proc = subprocess.Popen(
        [sys.executable, str(driver), "experiment=hbni_toy", *SLOW, f"hydra.run.dir={run_dir}"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _, stderr = proc.communicate(timeout=120)  # imports and the first kernel's compile, then seconds
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError("the run outlived a signal sent while numba compiled") from None
    name = signal.Signals(signum).name
    assert "signal sent from the compiler's callback" in stderr, stderr
    assert proc.returncode == -signum, stderr
    assert _status(run_dir) == {"status": "failed", "error": f"Stopped: stopped by {name}"}
    assert not (run_dir / ".run.lock").exists()


def test_ctrl_c_during_the_imports_ends_the_command_with_one_line(tmp_path):
    script = Path(sys.executable).with_name("hbni-pyro")
    proc = subprocess.Popen(
        [str(script), "experiment=hbni_toy", f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # the handlers are set first thing (SIGHUP's last; Python catches SIGINT from its start); Hydra, torch and numba
    # take seconds to import after them
    _wait_for(lambda: _caught(proc.pid, signal.SIGHUP), proc, "the command's signal handlers")
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGINT and (out, err) == ("", "stopped by SIGINT\n")
    assert not (tmp_path / "run").exists()


STUCK = """
import sys, time
from experiments.runs import signals
signals.install()
signals.begin(lambda error: print("marked failed:", error, flush=True))
said = False
while True:  # code that swallows every exception, the stop included (from before it says it is ready)
    try:
        if not said:
            said = True
            print("ready", flush=True)
        time.sleep(0.05)
    except BaseException:
        pass
"""


@pytest.mark.parametrize("second", [False, True], ids=["watchdog", "second signal"])
def test_a_stop_that_code_swallows_still_ends_the_process(second):
    proc = subprocess.Popen(
        [sys.executable, "-c", STUCK], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline() == "ready\n"
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    assert proc.stdout.readline() == "marked failed: Stopped: stopped by SIGTERM\n"  # at once, by the handler
    if second:
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    took = time.monotonic() - start
    if second:  # at once, by the second signal
        assert proc.returncode == -signal.SIGINT and took < GRACE_S, (took, err)
        assert err == "stopped by SIGINT (a second signal): ended at once\n"
    else:  # by the watchdog, the grace period after the signal
        assert proc.returncode == 128 + signal.SIGTERM and GRACE_S - 0.5 < took < GRACE_S + 10, (took, err)
        assert err.endswith(f"stopped by SIGTERM: the run did not end within {GRACE_S:g} s of the signal; ended it\n")
    assert out == ""  # marked failed once
