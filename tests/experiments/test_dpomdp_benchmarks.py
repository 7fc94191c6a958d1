"""Smoke run of the dpomdp_benchmarks experiment through the real Hydra entry point, tiny settings."""

import json
import subprocess
import sys
from pathlib import Path

from decpomdp import JointController

REPO = Path(__file__).resolve().parents[2]


def test_dpomdp_benchmarks_smoke(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "experiments.run", "experiment=dpomdp_benchmarks", f"hydra.run.dir={tmp_path}",
         "progress=false", "study.caps.iterations=2", "study.caps.samples=20", "study.caps.restarts=1",
         "study.random_controllers=10"],
        cwd=REPO, check=True, capture_output=True,
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    problems = metrics["problems"]
    assert set(problems) == {"broadcast_h10", "broadcast_h100", "dectiger_h3", "dectiger_h4", "recycling", "gridsmall"}
    for name, row in problems.items():
        assert row["controllers_evaluated"] == 2 * 20
        ctrl = JointController.load(tmp_path / "controllers" / f"{name}.safetensors")
        assert ctrl.num_controllers == 1
    assert problems["dectiger_h3"]["horizon"] == 3 and problems["recycling"]["horizon"] == "inf"
    assert (tmp_path / "gdice_learning_curves.png").stat().st_size > 10_000
