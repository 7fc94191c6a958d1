"""The ``slow`` marker: every test that starts an experiment process carries it, so ``-m "not slow"`` is quick."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def collected(*args: str) -> list[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "0", "--collect-only", *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    assert proc.returncode in (0, 5), proc.stdout + proc.stderr  # 5: nothing selected
    return [line for line in proc.stdout.splitlines() if "::" in line]


def test_whole_experiment_runs_are_slow_and_the_rest_is_not():
    runs = "tests/experiments/test_planning_experiments.py"  # two tests, each running its experiment twice
    unit = "tests/experiments/test_config_defaults.py"  # composes configs, starts no process
    slow, fast = collected(runs, unit, "-m", "slow"), collected(runs, unit, "-m", "not slow")
    assert slow and all(test.startswith(runs) for test in slow)
    assert fast and all(test.startswith(unit) for test in fast)


def test_modules_with_slow_tests_run_first_each_module_together():
    runs = "tests/experiments/test_planning_experiments.py"
    unit = "tests/experiments/test_config_defaults.py"
    order = [test.split("::")[0] for test in collected(unit, runs)]
    first_unit = order.index(unit)
    assert (
        order[0] == runs and all(m == runs for m in order[:first_unit]) and all(m == unit for m in order[first_unit:])
    )
