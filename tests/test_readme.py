"""The README's Python blocks run as written: in order, in one interpreter, as a reader pastes them.

The blocks that load a finished run need one: the test first runs the main job (the mission) with
the small settings the mission tests use, into ``outputs/mission/`` of a scratch directory, and
runs the blocks there.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
TINY_MISSION = [
    "mission.train_per_class=5", "mission.augment=0", "mission.calib_sequences=1", "mission.char_sequences=2",
    "mission.frames=5", "hbni.fit.num_chains=2", "hbni.fit.num_samples=40", "hbni.fit.warmup_steps=40",
    "planner.iterations=2", "planner.samples=6", "planner.elites=2", "study.rollouts=4", "study.reeval_rollouts=20",
    "progress=false", "mission.bank.sequences=2", "mission.bank.workers=0", "mission.generative_streams=50",
    "mission.bootstrap.replicates=2", "mission.bootstrap.rollouts=4",
    "cold_planner.budget=3000", "cold_planner.patience=1", "cold_planner.num_nodes=6", "cold_planner.start_nodes=3", "cold_planner.ce_iterations=2",
    "cold_planner.ce_samples=10", "cold_planner.ce_elites=2", "cold_planner.ce_memory=1", "cold_planner.ce_rollouts=4",
    "cold_planner.ce_screen_rollouts=2", "cold_planner.ls_candidates=40", "cold_planner.ls_stages=[[2,0.5],[4,2]]",
    "cold_planner.duel_rollouts=20", "cold_planner.visit_rollouts=10",
]


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 4


def test_readme_python_blocks_run_as_written(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run_dir = tmp_path / "outputs" / "mission" / "2026-01-01_00-00-00"
    subprocess.run([sys.executable, "-m", "experiments.run", "experiment=mission", f"hydra.run.dir={run_dir}",
                    f"mission.bank.cache_dir={tmp_path / 'banks'}", *TINY_MISSION], cwd=ROOT, check=True,
                   capture_output=True, env=env)
    script = "\n\n".join(BLOCKS)
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "MacroObservation(label=" in proc.stdout
