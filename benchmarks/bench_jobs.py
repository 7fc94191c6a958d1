"""Wall and CPU time of the main job and ``mission_full`` from a cold start, each in a fresh project root.

Each job runs as a user runs it (``python -m experiments.run experiment=<name> seed=<seed>``) in its own
process, with ``HBNI_PYRO_ROOT`` set to a new empty folder, so nothing is cached; the CPU time is the job's and
its children's (the bank's workers). The main job is the reference: ``mission_full`` is reported as a ratio.

    python -m benchmarks.bench_jobs [--jobs mission mission_full] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed_job(name: str, seed: int) -> tuple[float, float]:
    """(wall s, CPU s) of one cold run of ``experiment=name``."""
    with tempfile.TemporaryDirectory() as root:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "experiments.run", f"experiment={name}", f"seed={seed}", "progress=false"],
            cwd=ROOT,
            env={**os.environ, "HBNI_PYRO_ROOT": root},
            check=True,
            capture_output=True,
        )
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", nargs="+", default=["mission", "mission_full"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{'job':<14} {'wall':>10} {'CPU s':>8} {'wall / first':>13}")
    first = None
    for name in args.jobs:
        wall, cpu = timed_job(name, args.seed)
        first = first or wall
        print(f"{name:<14} {wall // 60:>4.0f} min {wall % 60:>2.0f} s {cpu:>8.0f} {wall / first:>12.2f}x", flush=True)


if __name__ == "__main__":
    main()
