"""``decpomdp.solve`` against ``paynt`` (FSC synthesis on the Storm model checker) on the shipped problems at the
discounted infinite horizon (gamma 0.9), both in this process under the same time limit.

``solve`` runs with its defaults (seed 0, one thread); ``paynt`` 0.5.0 synthesises a Dec-POMDP controller with
``--fsc-synthesis`` and ``memory_size`` memory nodes per observation, from the same problem written as a ``.dpomdp``
file with the discount set, stopped by its own timer at ``--limit`` seconds. ``solve`` runs every problem first, then
``paynt`` (so that nothing ``paynt``'s model checker leaves running counts in ``solve``'s CPU seconds); the model
checker's own messages (it tries other file formats first) are silenced. Prints both values, their ratio (solve /
paynt, where ``paynt``'s value is positive) and the CPU seconds. ``paynt`` is an optional benchmark dependency (``pip install paynt==0.5.0``);
without it the benchmark says so and runs ``solve`` alone.

    python -m benchmarks.bench_paynt [--limit 120] [--memory 2] [--problems dectiger recycling ...]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import sys
import tempfile
import time
from pathlib import Path

from decpomdp import solve
from decpomdp.dpomdp import load_problem, save_dpomdp

GAMMA = 0.9
PROBLEMS = ["dectiger", "broadcastChannel", "recycling", "GridSmall"]


@contextlib.contextmanager
def silenced():
    """File descriptors 1 and 2 to ``/dev/null`` (the model checker writes to them from C++)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def paynt_value(problem: str, limit: float, memory: int, folder: Path) -> float | None:
    """``paynt``'s value on ``problem`` at discount :data:`GAMMA` within ``limit`` seconds (``None``: no controller)."""
    import paynt.api
    import paynt.parser.sketch
    import paynt.utils.timer

    path = save_dpomdp(dataclasses.replace(load_problem(problem), discount=GAMMA), folder / f"{problem}.dpomdp")
    paynt.utils.timer.GlobalTimer.start(int(limit))
    with silenced():
        factory, task = paynt.parser.sketch.Sketch.load_sketch(
            str(path), str(folder / "none.props"), None, 0, 1e-4, None, False, task_kwargs={"memory_size": memory}
        )
        result = paynt.api.get_synthesizer(factory, task, "ar", True, None, False).run(None)
    return None if result is None or result.value is None else float(result.value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=float, default=120.0, help="seconds for each solver on each problem")
    parser.add_argument("--memory", type=int, default=2, help="paynt's memory nodes per observation")
    parser.add_argument("--problems", nargs="*", default=PROBLEMS)
    args = parser.parse_args()
    try:
        import paynt  # noqa: F401
    except ImportError:
        paynt_ok = False
        print("paynt is not installed (pip install paynt==0.5.0): solve runs alone")
    else:
        paynt_ok = True
    ours = {}
    for problem in args.problems:
        cpu = time.process_time()
        value = solve(problem, math.inf, GAMMA, seed=0).value
        ours[problem] = (value, time.process_time() - cpu)
        print(f"solve {problem}: {value:.4f} in {ours[problem][1]:.1f} CPU s", flush=True)
    lines = ["| problem | solve | CPU s | paynt | CPU s | solve / paynt |", "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for problem in args.problems:
            theirs, theirs_s = None, math.nan
            if paynt_ok:
                cpu = time.process_time()
                theirs = paynt_value(problem, args.limit, args.memory, Path(tmp))
                theirs_s = time.process_time() - cpu
            value, seconds = ours[problem]
            ratio = "n/a" if theirs is None or theirs <= 0 else f"{value / theirs:.4f}"
            shown = "n/a" if theirs is None else f"{theirs:.4f}"
            lines.append(f"| {problem} | {value:.4f} | {seconds:.1f} | {shown} | {theirs_s:.1f} | {ratio} |")
            print(lines[-1], flush=True)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
