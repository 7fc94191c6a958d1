"""``decpomdp.solve`` with its defaults (seed 0, one thread) on published optima: proofs of optimality at short
horizons, gaps at longer ones, discounted finite horizons and the discounted infinite horizon.

Each row prints the value, the best known value, their ratio, the upper bound, whether optimality is proven
(``bound - value <= 1e-6 |value|``), the CPU seconds and the controller size. Best known values: the MADP
toolbox's ``src/tests/optimalValueDatabase`` (problem, discount, horizon, value; 0.9 is stored as the float32
0.8999999761581421), masplan.org for Dec-Tiger h7-h10 (FB-HSVI, Dibangoye et al. 2013) and, at the infinite horizon,
FB-HSVI's 13.448 for Dec-Tiger (Dibangoye et al., JAIR 2016) and the database's longest horizons for Broadcast Channel
(h300) and Recycling (h200), which bound the infinite horizon's optimum from below to within ``0.9 ** h`` times the
largest reward.

    python -m benchmarks.bench_solve_acceptance [--rows dectiger:4:1 broadcastChannel:inf:0.9 ...]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from decpomdp import solve

G9 = 0.8999999761581421
BEST_KNOWN = {  # (problem, horizon, discount) -> value
    ("dectiger", 2, 1.0): -4.0,
    ("dectiger", 3, 1.0): 5.190812499999996,
    ("dectiger", 4, 1.0): 4.802755156249994,
    ("dectiger", 5, 1.0): 7.026450983203114,
    ("dectiger", 6, 1.0): 10.381625,
    ("broadcastChannel", 2, 1.0): 2.0,
    ("broadcastChannel", 3, 1.0): 2.99,
    ("broadcastChannel", 4, 1.0): 3.890000000000001,
    ("broadcastChannel", 5, 1.0): 4.790000000000001,
    ("recycling", 2, 1.0): 7.0,
    ("recycling", 3, 1.0): 10.660125,
    ("recycling", 4, 1.0): 13.38,
    ("GridSmall", 2, 1.0): 0.91,
    ("GridSmall", 3, 1.0): 1.550444,
    ("dectiger", 7, 1.0): 9.9935,
    ("dectiger", 8, 1.0): 12.217,
    ("dectiger", 9, 1.0): 15.572,
    ("dectiger", 10, 1.0): 15.184,
    ("dectiger", 4, G9): 2.455208016555325,
    ("dectiger", 6, G9): 6.301440187456018,
    ("GridSmall", 5, G9): 2.356548128997196,
    ("broadcastChannel", 10, G9): 6.124793466583204,
    ("broadcastChannel", 100, G9): 9.270770967154508,
    ("recycling", 10, G9): 21.20055873087291,
    ("recycling", 50, G9): 31.77054908739687,
    ("broadcastChannel", 45, 1.0): 40.96802748481747,
    ("broadcastChannel", 100, 1.0): 90.76042316921169,
    ("dectiger", math.inf, 0.9): 13.448,
    ("broadcastChannel", math.inf, 0.9): 9.271010730351492,
    ("recycling", math.inf, 0.9): 31.92912651652444,
}


def run(rows: list[tuple[str, float, float]], seed: int) -> list[dict]:
    out = []
    for problem, horizon, gamma in rows:
        cpu = time.process_time()
        s = solve(problem, horizon, gamma, seed=seed)
        cpu = time.process_time() - cpu
        best = BEST_KNOWN[problem, horizon, gamma]
        out.append(
            {
                "row": f"{problem} h{'inf' if math.isinf(horizon) else int(horizon)} gamma {gamma:.4g}",
                "value": s.value,
                "best_known": best,
                "fraction": 1.0 - (best - s.value) / abs(best),
                "bound": s.bound,
                "proven": s.proven,
                "cpu_s": cpu,
                "nodes": s.controller.num_nodes,
            }
        )
        r = out[-1]
        print(
            f"{r['row']}: value {r['value']:.6g}, best known {best:.6g} ({r['fraction']:.4f}), bound {r['bound']:.6g}, "
            f"proven {r['proven']}, {cpu:.1f} CPU s, {r['nodes']} nodes",
            flush=True,
        )
    return out


def table(results: list[dict]) -> str:
    lines = [
        "| row | value | best known | fraction | bound | proven | CPU s | nodes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r['row']} | {r['value']:.6g} | {r['best_known']:.6g} | {r['fraction']:.4f} | {r['bound']:.6g} | "
            f"{'yes' if r['proven'] else 'no'} | {r['cpu_s']:.1f} | {r['nodes']} |"
        )
    return "\n".join(lines)


def _row(item: str) -> tuple[str, float, float]:
    problem, horizon, gamma = item.split(":")
    gamma_value = G9 if float(gamma) == 0.9 and horizon != "inf" else float(gamma)
    return problem, math.inf if horizon == "inf" else float(int(horizon)), gamma_value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--rows",
        nargs="*",
        default=[f"{p}:{'inf' if math.isinf(h) else int(h)}:{g:.4g}" for p, h, g in BEST_KNOWN],
        help="problem:horizon:discount triples among the best known values (horizon inf: the infinite horizon)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    for item in args.rows:
        row = _row(item)
        key = (row[0], row[1] if math.isinf(row[1]) else int(row[1]), row[2])
        if key not in BEST_KNOWN:
            parser.error(f"--rows: {item!r} has no best known value here")
        rows.append(key)
    results = run(rows, args.seed)
    print(table(results))
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=2))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
