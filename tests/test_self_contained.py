"""A clone needs nothing beside it: no code, config or test points outside the repository."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = re.compile(r"\.\./shared|shared/benchmarks|/work/|/home/|/root/|/tmp/pytest|DESIGN\.md")


def _tracked(*patterns: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", *patterns], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [ROOT / line for line in out.splitlines() if line and line != "tests/test_self_contained.py"]


def test_no_path_outside_the_repository():
    files = _tracked("*.py", "*.yaml", "*.toml", "*.sh", "*.md", ".ci/*")
    assert len(files) > 50
    hits = [
        f"{f.relative_to(ROOT)}:{i}: {line.strip()}"
        for f in files
        for i, line in enumerate(f.read_text(errors="replace").splitlines(), 1)
        if OUTSIDE.search(line)
    ]
    assert not hits, "\n".join(hits)


def test_the_benchmark_problems_ship_with_their_licence():
    problems = ROOT / "decpomdp" / "dpomdp" / "problems"
    assert (problems / "COPYING").read_text().startswith("                    GNU GENERAL PUBLIC LICENSE")
    assert "MADP" in (problems / "README.md").read_text()
    from decpomdp.dpomdp import problem_names

    assert {"dectiger", "fireFighting_2_4_3"} <= set(problem_names())
