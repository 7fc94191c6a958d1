"""Shared pytest setup: the repository root and a single-threaded torch for small tensor programs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config: pytest.Config) -> None:
    """In the main process of a run with xdist workers, before they start: compile the numba kernels into their
    on-disk cache, in two processes side by side (``tests/compile_kernels.py``), so that the workers load them
    instead of each compiling them at once on a fresh machine. A run without workers compiles each kernel once
    anyway, where a test first needs it. A part that fails is reported; the tests that need it then fail."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return
    script = REPO_ROOT / "tests" / "compile_kernels.py"
    parts = ("package_delivery", "others")
    jobs = [subprocess.Popen([sys.executable, "-P", str(script), part], cwd=REPO_ROOT) for part in parts]
    for part, job in zip(parts, jobs, strict=True):
        if job.wait():
            print(f"tests/compile_kernels.py {part}: exit status {job.returncode}", file=sys.stderr)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
