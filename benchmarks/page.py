"""Rebuild ``docs/benchmarks.md`` from the benchmarks' own output.

Every ``benchmarks/bench_*.py`` runs in a fresh process (``python -m benchmarks.<name> [args]``) from the
repository's root; the page gets, per run, the benchmark's description (its docstring's first paragraph), the
command, the machine and date it ran on, and what it printed, verbatim. The page holds the project's only
measured figures; the other docs link to it.

Usage::

    python -m benchmarks.page                     # every benchmark (an hour or more on 2 cores)
    python -m benchmarks.page bench_render bench_simulator   # only these; the other sections are kept

A benchmark that fails keeps its previous section and the script exits non-zero, naming it.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

from hbni_infra.files import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "benchmarks.md"
RUNS: dict[str, list[list[str]]] = {
    "bench_planner_ablation": [["--domain", "disaster_relief"], ["--domain", "package_delivery"]],
    "bench_jobs": [["--jobs", "mission", "--together"]],
}
"""Benchmarks run with arguments (each list one run); the others run once with their defaults."""
SKIP = {"bench_devices"}
"""Benchmarks the page does not run: they need a GPU (their output is for the machine that has one)."""
HEADER = """# Benchmarks

Measured figures of the project, rebuilt by `python -m benchmarks.page` from what each benchmark in
`benchmarks/` prints (`python -m benchmarks.page <name> ...` reruns some and keeps the rest). Speed is
measured as ratios against a reference run in the same process, so that a loaded or slower machine moves
the absolute rates more than the ratios; each section says the machine and date it ran on.
"""


def benchmarks() -> list[str]:
    return sorted(p.stem for p in (ROOT / "benchmarks").glob("bench_*.py") if p.stem not in SKIP)


def description(name: str) -> str:
    """The first paragraph of the benchmark's docstring, on one line."""
    doc = ast.get_docstring(ast.parse((ROOT / "benchmarks" / f"{name}.py").read_text())) or name
    return " ".join(doc.split("\n\n")[0].split())


def machine() -> str:
    model = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        found = re.search(r"^model name\s*:\s*(.+)$", cpuinfo.read_text(), re.M)
        model = found.group(1).strip() if found else model
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    import numba
    import torch

    return (
        f"{model}, {cores} cores, Python {platform.python_version()}, torch {torch.__version__}, "
        f"numba {numba.__version__}"
    )


def run(name: str, args: list[str]) -> str:
    """The benchmark's printed output (``RuntimeError`` naming it when it fails)."""
    proc = subprocess.run([sys.executable, "-m", f"benchmarks.{name}", *args], cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{name} {' '.join(args)} failed:\n{proc.stderr[-2000:]}")
    return proc.stdout.strip()


def section(name: str, outputs: list[tuple[list[str], str]], where: str, when: str) -> str:
    body = [f"<!-- bench:{name} -->", f"## {name}", "", description(name), ""]
    for args, out in outputs:
        body += ["```bash", " ".join(["python -m", f"benchmarks.{name}", *args]), "```", "", "```text", out, "```", ""]
    body += [f"*{where}; {when}.*", f"<!-- /bench:{name} -->"]
    return "\n".join(body)


def sections(text: str) -> dict[str, str]:
    return {m.group(1): m.group(0) for m in re.finditer(r"<!-- bench:(\w+) -->.*?<!-- /bench:\1 -->", text, re.S)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="benchmarks to rerun (default: all)")
    names = parser.parse_args().names or benchmarks()
    unknown = sorted(set(names) - set(benchmarks()))
    if unknown:
        parser.error(f"names: unknown benchmarks {unknown}; expected some of {benchmarks()}")
    kept = sections(PAGE.read_text()) if PAGE.is_file() else {}
    where, failed = machine(), []
    for name in names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        try:
            outputs = [(args, run(name, args)) for args in RUNS.get(name, [[]])]
        except RuntimeError as exc:
            print(exc, file=sys.stderr)
            failed.append(name)
            continue
        kept[name] = section(name, outputs, where, datetime.date.today().isoformat())
        write(kept)
    print(f"wrote {PAGE}", file=sys.stderr)
    if failed:
        sys.exit(f"failed (their previous sections kept): {failed}")


def pending(name: str) -> str:
    """The section of a benchmark that has not run on this page yet."""
    return "\n".join(
        [
            f"<!-- bench:{name} -->",
            f"## {name}",
            "",
            description(name),
            "",
            f"Not run for this page yet: `python -m benchmarks.page {name}`.",
            f"<!-- /bench:{name} -->",
        ]
    )


def write(kept: dict[str, str]) -> None:
    """The page: every benchmark's section in name order, ``pending`` where it has none yet."""
    body = "\n\n".join(kept.get(n) or pending(n) for n in benchmarks())
    atomic_write_text(PAGE, HEADER + "\n" + body + "\n")


if __name__ == "__main__":
    main()
