"""What each part of ``decpomdp.solve`` contributes on exact scores: solve with one part removed at a time.

Variants, each on every row with the same seed (one thread):

* ``full``: the defaults (a planner run on a free graph and one on a layered graph, JESP on every result
  and from 20 random starts);
* ``no best responses``: ``best_responses=False`` (no JESP at all: the planner's results alone);
* ``no layered``: ``layer_width=0`` (free graphs only);
* ``no JESP restarts``: ``jesp_restarts=0`` (JESP only improves the planner's results);
* ``three runs of each``: ``restarts=3, layered_restarts=3``.

Rows are published finite-horizon optima (undiscounted; MADP toolbox, ``src/tests/optimalValueDatabase``, and
masplan.org's table for Dec-Tiger at horizon 8).
Prints a markdown table of the fraction of the optimum and the CPU seconds of every variant on every row,
and writes it as JSON to ``--out``.

    python -m benchmarks.bench_solve_ablation [--rows dectiger:4 ...] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from decpomdp import solve

OPTIMA = {  # (problem, horizon) -> optimum: MADP toolbox optimalValueDatabase; dectiger h8: masplan.org
    ("dectiger", 4): 4.802755,
    ("dectiger", 5): 7.026451,
    ("broadcastChannel", 6): 5.69,
    ("recycling", 6): 19.5542,
    ("recycling", 9): 28.7870366,
    ("GridSmall", 4): 2.241577,
    ("dectiger", 8): 12.217,
}
VARIANTS = {
    "full": {},
    "no best responses": {"best_responses": False},
    "no layered": {"layer_width": 0},
    "no JESP restarts": {"jesp_restarts": 0},
    "three runs of each": {"restarts": 3, "layered_restarts": 3},
}


def run(rows: list[tuple[str, int]], seed: int) -> dict[str, dict[str, dict[str, float]]]:
    """``{variant: {row: {"value", "fraction", "cpu_s"}}}``."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, settings in VARIANTS.items():
        out[name] = {}
        for problem, horizon in rows:
            cpu = time.process_time()
            s = solve(problem, horizon, 1.0, seed=seed, **settings)
            out[name][f"{problem} h{horizon}"] = {
                "value": s.value,
                "fraction": s.value / OPTIMA[problem, horizon],
                "gap": s.gap,
                "cpu_s": time.process_time() - cpu,
            }
            print(
                f"{name:>18} {problem} h{horizon}: {s.value:.4f} ({s.value / OPTIMA[problem, horizon]:.4f} of the "
                f"optimum) in {out[name][f'{problem} h{horizon}']['cpu_s']:.1f} CPU s",
                file=sys.stderr,
                flush=True,
            )  # progress; the table is the result
    return out


def table(results: dict[str, dict[str, dict[str, float]]]) -> str:
    rows = list(next(iter(results.values())))
    lines = ["| variant | " + " | ".join(rows) + " | total CPU s |", "|---" * (len(rows) + 2) + "|"]
    for name, per_row in results.items():
        cells = [f"{per_row[r]['fraction']:.4f} ({per_row[r]['cpu_s']:.1f} s)" for r in rows]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sum(v['cpu_s'] for v in per_row.values()):.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--rows",
        nargs="*",
        default=[f"{p}:{h}" for p, h in OPTIMA],
        help="problem:horizon pairs among the published optima",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    for item in args.rows:
        problem, _, horizon = item.partition(":")
        if (problem, int(horizon)) not in OPTIMA:
            parser.error(f"--rows: {item!r} is not one of {', '.join(f'{p}:{h}' for p, h in OPTIMA)}")
        rows.append((problem, int(horizon)))
    results = run(rows, args.seed)
    print(table(results))
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
