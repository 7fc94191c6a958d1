"""Wall and CPU time of the main job, ``mission_full`` and the test suite at an older commit and at this one, side by side.

Both commits run on the same machine in one invocation, interleaved (older, this, then this, older, ... for
``--repeats``), or with ``--together`` both at the same time (on a machine others share, both then see the same
load), so that a loaded or slower machine slows both alike; the ratios this / older are the figures.
Each job starts cold: ``mission`` and ``mission_full`` run as a user runs them (``python -m experiments.run
experiment=<name> seed=<seed>``) with ``HBNI_PYRO_ROOT`` and ``NUMBA_CACHE_DIR`` new empty folders; ``suite`` is
the README's test command (``scripts/bootstrap.sh && .venv/bin/python -m pytest``) in a fresh clone, its pytest
timed apart from the install. The older commit's jobs run in a clone of it in a temporary folder, with this
interpreter when its dependencies (``pyproject.toml``, ``constraints.txt``) are this commit's, else with a virtual
environment made for it. CPU seconds are the job's and its children's (bank workers, test workers). The output
also gives the machine's speed beside the absolute times: one core's float32 matmul GFLOP/s (1024 x 1024, one
thread), and the load average after each run (other work on the machine slows the runs it overlaps).

    python -m benchmarks.bench_jobs [--base d04ec89] [--jobs mission mission_full suite] [--seed 0] [--repeats 1]
        [--together] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import torch

ROOT = Path(__file__).resolve().parents[1]
JOBS = ("mission", "mission_full", "suite")
DEPENDENCIES = ("pyproject.toml", "constraints.txt")
"""Files that decide a checkout's environment: an older commit with the same ones runs with this interpreter."""


class Timing(NamedTuple):
    """One run of a job: wall and CPU seconds (its own and its children's), the 1-minute load average after it and
    its exit status (a failed run is timed and reported, not retried)."""

    wall: float
    cpu: float
    load: float
    status: int = 0


def matmul_gflops(size: int = 1024, repeats: int = 20) -> float:
    """One core's float32 matmul rate, GFLOP/s of CPU time: the best of ``repeats`` ``size x size`` products on one
    thread, each timed by this process's CPU clock (other work on a shared machine does not count)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        a, b = torch.randn(size, size), torch.randn(size, size)
        a @ b  # warm up
        best = float("inf")
        for _ in range(repeats):
            start = time.process_time()
            a @ b
            best = min(best, time.process_time() - start)
    finally:
        torch.set_num_threads(before)
    return 2 * size**3 / max(best, 1e-9) / 1e9


def timed(command: Sequence[str], cwd: Path, env: dict[str, str], log: Path | None = None) -> Timing:
    """Run ``command`` to completion, its output into ``log`` (default: discarded). Its CPU time is its own and its
    waited-for descendants' (``wait4``), so runs side by side are timed apart."""
    start = time.perf_counter()
    with open(os.devnull if log is None else log, "w") as out:
        proc = subprocess.Popen(list(command), cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - start
    return Timing(wall, usage.ru_utime + usage.ru_stime, os.getloadavg()[0], proc.returncode)


def clone(commit: str, into: Path) -> Path:
    """A clean clone of this repository at ``commit`` in ``into`` (no build outputs, caches or environment)."""
    subprocess.run(["git", "clone", "--quiet", "--no-checkout", str(ROOT), str(into)], check=True)
    subprocess.run(["git", "-C", str(into), "checkout", "--quiet", "--detach", commit], check=True)
    return into


def same_dependencies(a: Path, b: Path) -> bool:
    """Whether checkouts ``a`` and ``b`` install the same environment (:data:`DEPENDENCIES` alike)."""
    return all((a / f).read_bytes() == (b / f).read_bytes() for f in DEPENDENCIES)


class Version(NamedTuple):
    """A commit to time: its checkout and the interpreter its main jobs run with."""

    label: str
    tree: Path
    python: str


def prepare(base: str, scratch: Path) -> tuple[Version, Version]:
    """The older commit (a clone of ``base`` under ``scratch``, with this interpreter if the dependencies match, else
    its own ``scripts/bootstrap.sh`` environment) and this checkout, with this interpreter."""
    tree = clone(base, scratch / "base")
    python = sys.executable
    if not same_dependencies(tree, ROOT):
        print(f"{base}: other dependencies than this checkout's; installing its environment", file=sys.stderr)
        subprocess.run(["scripts/bootstrap.sh"], cwd=tree, check=True)
        python = str(tree / ".venv" / "bin" / "python")
    return Version(short(base), tree, python), Version(short("HEAD"), ROOT, sys.executable)


def short(commit: str) -> str:
    return subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", commit], check=True, capture_output=True, text=True
    ).stdout.strip()


def run_job(name: str, version: Version, seed: int, folder: Path) -> dict[str, Timing]:
    """One cold run of job ``name`` at ``version`` in the new folder ``folder`` (its project root, numba cache, clone
    and ``log``): ``{name: timing}``, and for ``suite`` also its install (``suite install``) and its pytest alone
    (``suite pytest``)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder / "numba")}
    if name != "suite":
        env.update(HBNI_PYRO_ROOT=str(folder / "root"), PYTHONPATH=str(version.tree))
        command = [version.python, "-m", "experiments.run", f"experiment={name}", f"seed={seed}", "progress=false"]
        return {name: timed(command, version.tree, env, folder / "log")}
    tree = clone(version.label, folder / "clone")
    install = timed(["scripts/bootstrap.sh"], tree, env, folder / "install.log")
    tests = timed([".venv/bin/python", "-m", "pytest"], tree, env, folder / "log")
    both = Timing(install.wall + tests.wall, install.cpu + tests.cpu, tests.load, install.status or tests.status)
    return {name: both, "suite install": install, "suite pytest": tests}


def minutes(seconds: float) -> str:
    return f"{seconds // 60:.0f} min {seconds % 60:02.0f} s"


def table(old: str, new: str, runs: dict[str, dict[str, list[Timing]]]) -> list[str]:
    """Rows per job: both versions' wall and CPU seconds (summed over repeats) and the ratios new / old."""
    lines = [
        f"{'job':<14} {'wall ' + old:>13} {'wall ' + new:>13} {'ratio':>6} {'CPU s ' + old:>13} "
        f"{'CPU s ' + new:>13} {'ratio':>6}"
    ]
    for job, by in runs.items():
        if not (by.get(old) and by.get(new)):
            continue
        wo, wn = sum(t.wall for t in by[old]), sum(t.wall for t in by[new])
        co, cn = sum(t.cpu for t in by[old]), sum(t.cpu for t in by[new])
        lines.append(
            f"{job:<14} {minutes(wo):>13} {minutes(wn):>13} {wn / wo:>5.2f}x {co:>13.0f} {cn:>13.0f} {cn / co:>5.2f}x"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="d04ec89", help="the older commit (default: d04ec89)")
    parser.add_argument("--jobs", nargs="+", choices=JOBS, default=["mission", "mission_full"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=1, help="interleaved runs of each job per commit")
    parser.add_argument(
        "--together", action="store_true", help="run both commits' runs of a job at the same time (a busy machine)"
    )
    parser.add_argument("--keep", help="keep every run's folder (project root, log) under this new folder")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats: expected an int >= 1, got {args.repeats}")
    if args.keep and Path(args.keep).exists():
        parser.error(f"--keep: expected a new folder, {args.keep} exists")
    print(f"one core: {matmul_gflops():.1f} GFLOP/s (float32 matmul 1024 x 1024, one thread)", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-jobs-") as scratch:
        keep = Path(args.keep or scratch)
        old, new = prepare(args.base, Path(scratch))
        how = "this interpreter" if old.python == sys.executable else "its own environment"
        print(f"older: {old.label} (a clean clone, {how}); this: {new.label}, seed {args.seed}", flush=True)
        print(f"{'job':<14} {'commit':<9} {'wall':>13} {'CPU s':>7} {'load after':>10}", flush=True)
        runs: dict[str, dict[str, list[Timing]]] = {}
        for job in args.jobs:
            for repeat in range(args.repeats):
                folders = {v.label: keep / f"{job}-{v.label}-{repeat}" for v in (old, new)}
                for folder in folders.values():
                    folder.mkdir(parents=True)
                with ThreadPoolExecutor(2 if args.together else 1) as pool:
                    done = [
                        (v, pool.submit(run_job, job, v, args.seed, folders[v.label]))
                        for v in ((old, new) if repeat % 2 == 0 else (new, old))
                    ]
                    for version, future in done:
                        for name, t in future.result().items():
                            runs.setdefault(name, {}).setdefault(version.label, []).append(t)
                            failed = f"  failed (exit {t.status}; {folders[version.label] / 'log'})" if t.status else ""
                            print(
                                f"{name:<14} {version.label:<9} {minutes(t.wall):>13} {t.cpu:>7.0f} "
                                f"{t.load:>10.2f}{failed}",
                                flush=True,
                            )
    print("\n".join(["", *table(old.label, new.label, runs)]))
    if any(t.status for by in runs.values() for ts in by.values() for t in ts):
        sys.exit("some runs failed (see their lines)")


if __name__ == "__main__":
    main()
