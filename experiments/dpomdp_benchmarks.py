"""G-DICE on the standard Dec-POMDP benchmarks (MADP .dpomdp files), scored by exact evaluation.

For every problem in ``study.problems`` the run loads the file as a unit-duration Dec-POSMDP with the
configured discount and horizon (``null`` = infinite, discounted), runs G-DICE ``restarts`` times with
exact controller values as the evaluator, keeps the best controller, and compares its exact value
with the problem's target. Writes ``gdice_learning_curves.png``, one controller file per problem in
``controllers/`` and returns the table as metrics.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from decpomdp import gdice, random_controllers
from decpomdp.dpomdp import ExactEvaluator, TabularDecPOSMDP, exact_value
from experiments.common import save_figure

REPO = Path(__file__).resolve().parents[1]


def _cap(value: int, cap: int | None) -> int:
    return value if cap is None else min(value, int(cap))


def _solve(name: str, spec: DictConfig, planner: DictConfig, study: DictConfig, bench: Path, seed: int,
           progress: bool) -> tuple[dict, list[float], object]:
    horizon = math.inf if spec.horizon is None else float(spec.horizon)
    env = TabularDecPOSMDP.from_file(bench / spec.file, gamma=float(spec.gamma), horizon=horizon)
    merged = OmegaConf.merge(planner, spec.gdice)
    merged.iterations = _cap(merged.iterations, study.caps.iterations)
    merged.samples = _cap(merged.samples, study.caps.samples)
    merged.elites = min(merged.elites, merged.samples)
    cfg = instantiate(merged)
    evaluator = ExactEvaluator(env)
    restarts = _cap(int(spec.restarts), study.caps.restarts)
    runs, start = [], time.perf_counter()
    for r in range(restarts):
        res = gdice(evaluator, env.num_agents, env.num_actions, env.num_obs, cfg, seed=seed * 1000 + r,
                    reevaluator=evaluator, progress=progress)
        runs.append(res)
    elapsed = time.perf_counter() - start
    best = max(runs, key=lambda res: res.value)
    value = exact_value(env, best.best).item()
    g = torch.Generator().manual_seed(seed)
    rand = exact_value(env, random_controllers(int(study.random_controllers), env.num_agents, cfg.num_nodes,
                                               env.num_actions, env.num_obs, g))
    row = {
        "file": spec.file,
        "gamma": float(spec.gamma),
        "horizon": "inf" if horizon == math.inf else int(horizon),
        "gdice_value": value,
        "restart_values": [res.value for res in runs],
        "optimum": spec.optimum,
        "target": spec.target,
        "fraction_of_optimum": None if spec.optimum is None else value / float(spec.optimum),
        "meets_target": None if spec.target is None else bool(value >= float(spec.target) - 1e-9),
        "random_controller_mean": rand.mean().item(),
        "random_controller_stderr": (rand.std() / math.sqrt(rand.numel())).item(),
        "controllers_evaluated": restarts * cfg.iterations * cfg.samples,
        "seconds": elapsed,
        "settings": {**OmegaConf.to_container(merged), "restarts": restarts},
    }
    return row, best.history["best"], best.best


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study = cfg.study
    bench = Path(study.benchmark_dir)
    bench = bench if bench.is_absolute() else REPO / bench
    if not bench.is_dir():
        raise FileNotFoundError(f"study.benchmark_dir: no directory {str(bench)!r}")
    table, curves = {}, {}
    for name, spec in study.problems.items():
        row, curve, controller = _solve(name, spec, cfg.planner, study, bench, int(cfg.seed), bool(cfg.progress))
        controller.save(run_dir / "controllers" / f"{name}.safetensors")
        table[name], curves[name] = row, curve
        print(f"{name}: G-DICE {row['gdice_value']:.4f} (target {row['target']}, optimum {row['optimum']}, "
              f"random {row['random_controller_mean']:.3f}) in {row['seconds']:.1f} s", flush=True)
    _plot(curves, table, run_dir / "gdice_learning_curves.png")
    met = [row["meets_target"] for row in table.values() if row["meets_target"] is not None]
    return {"problems": table, "all_targets_met": all(met), "targets_met": sum(met), "targets": len(met)}


def _plot(curves: dict, table: dict, path: Path) -> None:
    n = len(curves)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, (name, curve) in zip(axes.ravel(), curves.items()):
        row = table[name]
        ax.plot(range(1, len(curve) + 1), curve, color="C0", label="G-DICE best (exact)")
        if row["optimum"] is not None:
            ax.axhline(row["optimum"], color="k", ls="--", lw=1, label="optimum / best known")
        if row["target"] is not None:
            ax.axhline(row["target"], color="C3", ls=":", lw=1, label="target")
        ax.set_title(f"{name} (gamma {row['gamma']}, h {row['horizon']})\n"
                     f"random controllers: {row['random_controller_mean']:.3g} on average", fontsize=9)
        ax.set_xlabel("iteration")
        ax.set_ylabel("value")
        lo = min(curve[0], row["target"] if row["target"] is not None else curve[0])
        hi = max(curve[-1], row["optimum"] if row["optimum"] is not None else curve[-1])
        ax.set_ylim(lo - 0.1 * (hi - lo + 1e-9), hi + 0.1 * (hi - lo + 1e-9))
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle("G-DICE on the .dpomdp benchmarks (best restart, best controller so far)")
    fig.tight_layout()
    save_figure(fig, path)
