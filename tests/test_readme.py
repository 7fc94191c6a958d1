"""The README's Python blocks run as written: each alone in a fresh interpreter, as a reader pastes it. A block
whose first line is a comment starting ``# continues`` runs after the block before it, in the same interpreter.

The blocks that load a finished run need one: the test first runs the main job (the mission) with
the small settings the mission tests use, into ``outputs/mission/`` of a scratch directory made the project
root (``HBNI_PYRO_ROOT``), and runs the blocks there. The robot section's blocks run from the installed wheel
instead (tests/test_packaging.py).
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
# docs/engine.md's domain is tested by tests/decpomdp
DOCS = ("mission", "noise_models", "new_place", "planner", "dpomdp", "arviz")


def groups(blocks: list[str]) -> list[str]:
    """The blocks as the scripts a reader runs: each alone, or joined to the one before when it says it continues it."""
    out: list[str] = []
    for block in blocks:
        if block.startswith("# continues") and out:
            out[-1] += "\n\n" + block
        else:
            out.append(block)
    return out


SCRIPTS = groups(BLOCKS)
SECTIONS = {
    section.splitlines()[0]: groups(re.findall(r"```python\n(.*?)```", section, re.S))
    for section in re.split(r"^## ", (ROOT / "README.md").read_text(), flags=re.M)
}
"""Section title -> its scripts."""
ON_THE_WHEEL = "Run a saved policy on a robot"
"""The section whose scripts tests/test_packaging.py runs from the installed wheel, on the README's robot install (in
a fresh interpreter outside the checkout); they do not run here a second time."""
HERE = [script for title, scripts in SECTIONS.items() if title != ON_THE_WHEEL for script in scripts]
DOC_SCRIPTS = [
    (name, script)
    for name in DOCS
    for script in groups(re.findall(r"```python\n(.*?)```", (ROOT / "docs" / f"{name}.md").read_text(), re.S))
]


def project_env(root: Path) -> dict[str, str]:
    """The environment that makes ``root`` the project root (``outputs/`` under it), with the package importable."""
    return {**os.environ, "PYTHONPATH": str(ROOT), "HBNI_PYRO_ROOT": str(root)}


def run_script(script: str, root: Path) -> subprocess.CompletedProcess:
    """``script`` in a fresh interpreter, in ``root`` made the project root."""
    return subprocess.run(
        [sys.executable, "-c", script], cwd=root, capture_output=True, text=True, env=project_env(root)
    )


@pytest.fixture(scope="module")
def finished_run(tiny_mission_run) -> Path:
    """A scratch project root holding one finished main-job run (the mission tests' small settings)."""
    return tiny_mission_run.parents[2]


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 4 and len(SCRIPTS) >= 3  # the robot loop continues the block that writes its files
    assert len(SECTIONS[ON_THE_WHEEL]) == 1 and len(HERE) == len(SCRIPTS) - 1  # the robot's, run from the wheel
    assert any("latest_run(" in s for s in SCRIPTS) and any("print(process.run(" in s for s in SCRIPTS)
    assert len(DOC_SCRIPTS) >= 4


@pytest.mark.parametrize(
    "index", [pytest.param(i, marks=[pytest.mark.slow] if "latest_run(" in s else []) for i, s in enumerate(HERE)]
)
def test_readme_python_blocks_run_as_written(index, tmp_path, request):
    script = HERE[index]
    root = request.getfixturevalue("finished_run") if "latest_run(" in script else tmp_path
    proc = run_script(script, root)
    assert proc.returncode == 0, f"this block fails alone:\n{script}\n{proc.stderr[-3000:]}"
    if "print(process.run(" in script:
        assert "MacroObservation(label=" in proc.stdout


@pytest.mark.parametrize(("name", "script"), DOC_SCRIPTS, ids=[f"{n}-{i}" for i, (n, _) in enumerate(DOC_SCRIPTS)])
def test_docs_python_blocks_run_as_written(name, script, tmp_path):
    proc = run_script(script, tmp_path)
    assert proc.returncode == 0, f"this block of docs/{name}.md fails alone:\n{script}\n{proc.stderr[-3000:]}"


def test_the_readme_stays_short_and_its_links_resolve():
    """It reads in ten minutes (2500 words at 250 a minute) and no section grows long: longer material goes to
    docs/."""
    text = (ROOT / "README.md").read_text()
    assert len(text.split()) <= 2500
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    assert len(sections) >= 6
    assert {s.splitlines()[0]: len(s.splitlines()) for s in sections if len(s.splitlines()) > 80} == {}
    links = re.findall(r"\]\(((?:docs)/[^)]+)\)", text)
    assert len(links) >= 8 and all((ROOT / link).exists() for link in links), links
