"""The README's Python blocks run as written: each alone in a fresh interpreter, as a reader pastes it. A block
whose first line is a comment starting ``# continues`` runs after the block before it, in the same interpreter.

The blocks that load a finished run need one: the test first runs the main job (the mission) with
the small settings the mission tests use, into ``outputs/mission/`` of a scratch directory made the project
root (``HBNI_PYRO_ROOT``), and runs the blocks there.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

from mission_tiny import TINY_MISSION

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
DOCS = ("mission", "noise_models", "planner", "dpomdp")  # docs/engine.md's domain is tested by tests/decpomdp


def groups(blocks: list[str]) -> list[str]:
    """The blocks as the scripts a reader runs: each alone, or joined to the one before when it says it continues it."""
    out: list[str] = []
    for block in blocks:
        if block.startswith("# continues") and out:
            out[-1] += "\n\n" + block
        else:
            out.append(block)
    return out


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 4 and len(groups(BLOCKS)) >= 3  # the robot loop continues the block that writes its files


def test_readme_python_blocks_run_as_written(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HBNI_PYRO_ROOT": str(tmp_path)}  # outputs/ of the scratch folder
    run_dir = tmp_path / "outputs" / "mission" / "2026-01-01_00-00-00"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments.run",
            "experiment=mission",
            f"hydra.run.dir={run_dir}",
            f"mission.bank.cache_dir={tmp_path / 'banks'}",
            *TINY_MISSION,
        ],
        cwd=ROOT,
        check=True,
        capture_output=True,
        env=env,
    )
    printed = ""
    for script in groups(BLOCKS):
        proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, env=env)
        assert proc.returncode == 0, f"this block fails alone:\n{script}\n{proc.stderr[-3000:]}"
        printed += proc.stdout
    assert "MacroObservation(label=" in printed


def test_docs_python_blocks_run_as_written(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HBNI_PYRO_ROOT": str(tmp_path)}
    blocks = {
        name: re.findall(r"```python\n(.*?)```", (ROOT / "docs" / f"{name}.md").read_text(), re.S) for name in DOCS
    }
    assert sum(map(len, blocks.values())) >= 4
    for name, found in blocks.items():
        for script in groups(found):
            proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, env=env)
            assert proc.returncode == 0, f"this block of docs/{name}.md fails alone:\n{script}\n{proc.stderr[-3000:]}"


def test_the_readme_stays_short_and_its_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 215  # longer material goes to docs/
    links = re.findall(r"\]\(((?:docs)/[^)]+)\)", text)
    assert len(links) >= 8 and all((ROOT / link).exists() for link in links), links
