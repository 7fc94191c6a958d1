"""``decpomdp.solve`` with its defaults (seed 0, one thread) on every published optimum of the shipped problems up to
horizon 10 (at the discount it is stored with), Broadcast Channel's horizons 45-100 and the discounted infinite
horizon: proofs of optimality at short horizons, gaps at longer ones.

The rows are those of ``conf/experiment/dpomdp_benchmarks.yaml`` with a published optimum (each cites its source: the
MADP toolbox's ``src/tests/optimalValueDatabase``, where 0.9 is stored as the float32 0.8999999761581421, masplan.org,
and at the infinite horizon FB-HSVI's 13.448 for Dec-Tiger and the database's longest horizons for Broadcast Channel
and Recycling, which bound the infinite horizon's optimum from below to within ``0.9 ** h`` times the largest
reward); GridSmall's infinite horizon, which has none, is compared with ``paynt``'s 6.687 (``bench_paynt``). Each row
prints the value, the best known value, the fraction of it reached (``1 - (best - value) / |best|``; a best known 0:
1 when reached, else 0), the upper bound, whether optimality is proven (``bound - value <= 1e-6 |value|``), the CPU seconds
and the controller size; the last lines name the rows below 0.99 of the best known value or over their CPU limit
(60 s at a finite horizon, 120 s at the infinite one).

    python -m benchmarks.bench_solve_acceptance [--rows dectiger_h4 broadcast_inf dectiger:5:1 ...]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import yaml

from decpomdp import solve
from experiments.studies.dpomdp_benchmarks import fraction_of_optimum

TABLE = Path(__file__).resolve().parents[1] / "conf" / "experiment" / "dpomdp_benchmarks.yaml"
MAX_HORIZON = 10
"""Longest finite horizon of every problem's rows (Broadcast Channel also runs :data:`LONG_BROADCAST`)."""
LONG_BROADCAST = (45, 100)
"""Broadcast Channel's long horizons (from, to) that the acceptance covers."""
PAYNT_GRIDSMALL = 6.687
"""``paynt`` 0.5.0's value on GridSmall at gamma 0.9 in 60 s with 2 memory nodes (the reference where no optimum is
published)."""
FRACTION = 0.99
"""Fraction of the best known value a row must reach."""
CPU_LIMIT = {"finite": 60.0, "infinite": 120.0}
"""CPU seconds a row may take."""


def rows() -> dict[str, tuple[str, float, float, float]]:
    """``name -> (problem, horizon, discount, best known)`` of the acceptance rows (horizon ``math.inf``: infinite)."""
    out = {}
    for name, row in yaml.safe_load(TABLE.read_text())["study"]["rows"].items():
        h, problem, best = row["horizon"], row["problem"], row["optimum"]
        if h is None:
            out[name] = (problem, math.inf, float(row["gamma"]), PAYNT_GRIDSMALL if best is None else float(best))
        elif best is not None and (
            h <= MAX_HORIZON or (problem == "broadcastChannel" and LONG_BROADCAST[0] <= h <= LONG_BROADCAST[1])
        ):
            out[name] = (problem, float(h), float(row["gamma"]), float(best))
    return out


def run(selected: dict[str, tuple[str, float, float, float]], seed: int) -> list[dict]:
    out = []
    for name, (problem, horizon, gamma, best) in selected.items():
        cpu = time.process_time()
        s = solve(problem, horizon, gamma, seed=seed)
        cpu = time.process_time() - cpu
        limit = CPU_LIMIT["infinite" if math.isinf(horizon) else "finite"]
        fraction = fraction_of_optimum(s.value, best, best)
        r = {
            "row": name,
            "problem": problem,
            "horizon": "inf" if math.isinf(horizon) else int(horizon),
            "gamma": gamma,
            "value": s.value,
            "best_known": best,
            "fraction": fraction,
            "bound": s.bound,
            "gap": s.gap,
            "proven": s.proven,
            "cpu_s": cpu,
            "nodes": s.controller.num_nodes,
            "passed": fraction >= FRACTION and cpu <= limit,
        }
        out.append(r)
        print(
            f"{name} ({problem} h{r['horizon']} gamma {gamma:.4g}): value {s.value:.6g}, best known {best:.6g} "
            f"({r['fraction']:.4f}), bound {s.bound:.6g}, proven {s.proven}, {cpu:.1f} CPU s, {r['nodes']} nodes",
            flush=True,
        )
    return out


def table(results: list[dict]) -> str:
    lines = [
        "| row | h | gamma | value | best known | fraction | bound | gap | proven | CPU s | nodes |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['row']} | {r['horizon']} | {r['gamma']:.4g} | {r['value']:.6g} | {r['best_known']:.6g} | "
            f"{r['fraction']:.4f} | {r['bound']:.6g} | {r['gap']:.2%} | {'yes' if r['proven'] else 'no'} | "
            f"{r['cpu_s']:.1f} | {r['nodes']} |"
        )
    return "\n".join(lines)


def select(items: list[str], known: dict[str, tuple[str, float, float, float]]) -> dict:
    """The rows named by ``items``: row names, or ``problem:horizon:discount`` (horizon ``inf``; a discount matches
    every row within 1e-6 of it, so 0.9 also takes the float32 0.8999999761581421)."""
    chosen = {}
    for item in items:
        if item in known:
            chosen[item] = known[item]
            continue
        parts = item.split(":")
        if len(parts) != 3:
            raise ValueError(f"--rows: {item!r} is neither a row name nor problem:horizon:discount")
        problem, horizon, gamma = parts[0], float(parts[1]), float(parts[2])
        hits = {n: r for n, r in known.items() if r[0] == problem and r[1] == horizon and abs(r[2] - gamma) <= 1e-6}
        if not hits:
            raise ValueError(f"--rows: {item!r} has no row with a best known value; the rows are {sorted(known)}")
        chosen.update(hits)
    return chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="*", default=None, help="row names or problem:horizon:discount (default: all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    known = rows()
    try:
        selected = known if args.rows is None else select(args.rows, known)
    except ValueError as exc:
        parser.error(str(exc))
    results = run(selected, args.seed)
    print(table(results))
    missed = [r for r in results if not r["passed"]]
    print(
        f"{len(results) - len(missed)} of {len(results)} rows reach {FRACTION} of the best known value within their CPU limit"
    )
    for r in missed:
        print(f"missed: {r['row']}: fraction {r['fraction']:.4f}, {r['cpu_s']:.1f} CPU s")
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
