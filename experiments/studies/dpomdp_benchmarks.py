"""``solve`` and G-DICE on the standard Dec-POMDP benchmarks shipped with the package, against published optima.

Every row of ``study.rows`` is one shipped problem at a finite horizon (undiscounted unless set) or
discounted with an infinite horizon. The run checks every row before any work, then for each row runs
G-DICE ``restarts`` times at the row's settings (the paper's budget by default: N_s = 100 samples,
N_k = 100 iterations), scoring controllers exactly (``evaluator: exact``) or by Monte Carlo rollouts
(``evaluator: monte_carlo``), and reports the best controller's exact value next to the optimum.

*Fraction of the optimum* is ``1 - (V* - V) / |V*|``: G-DICE's shortfall relative to the size of the
optimum, which is ``V / V*`` when ``V* > 0`` and stays meaningful when ``V* < 0`` (V* = -4, V = -4.2
gives 0.95). Where ``V* = 0`` the shortfall is scaled by the random controllers' shortfall instead.
A row *meets* 95 % when that fraction is at least 0.95. Also reported: the share of the gap from the
random-controller mean to the optimum that G-DICE closed, and, at horizon 2, the optimum found by
exhaustive search over every deterministic joint policy (a check that a published number belongs to
the shipped file; where nothing is published it is the row's optimum, labelled as computed here).

Every row also runs :func:`decpomdp.solve` with the one setting ``study.solve`` (no row tunes it):
its exact value, fraction of the optimum, upper bound, certified gap ``(bound - value) / |bound|``, whether
optimality is proven (``bound - value <= 1e-6 |value|``), seconds and controller size; a row *meets* 99 % when
that fraction is at least 0.99.

Writes ``metrics.json`` (the table), ``table.md``, ``dpomdp_benchmarks.png`` and two controller files
per row in ``controllers/`` (``<row>.safetensors``: G-DICE's, ``<row>_solve.safetensors``: solve's).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

from decpomdp import solve
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value
from decpomdp.dpomdp.exhaustive import exhaustive_optimum
from decpomdp.search import ExactScorer, PlannerConfig, RolloutScorer, plan
from decpomdp.search.cross_entropy import layered_mask, sample_controllers
from experiments.runs.outputs import save_figure
from experiments.schemas.planning_studies import BenchmarkStudy, DPOMDPBenchmarks
from hbni_infra.files import atomic_write_text
from hbni_infra.threads import set_threads
from hbni_infra.streams import stream_seed, torch_stream


@dataclass(frozen=True)
class Row:
    """One benchmark row (``study.rows.<name>`` in the config, checked there): its horizon ``inf`` when infinite."""

    name: str
    problem: str
    gamma: float
    horizon: float
    optimum: float | None
    source: str
    evaluator: str
    rollouts: int
    restarts: int
    gdice: dict = field(default_factory=dict)


def build_rows(study: BenchmarkStudy, planner: Any) -> list[tuple[Row, PlannerConfig, PlannerConfig]]:
    """Every row, its G-DICE settings (the ``planner`` block overridden by the row, then capped) and the same at the
    paper's budget, built up front: a row's planner settings that do not make a planner fail here, naming it."""
    base: PlannerConfig = instantiate(planner)
    budget = dataclasses.asdict(study.paper_budget)
    rows = []
    for name, spec in study.rows.items():
        horizon = math.inf if spec.horizon is None else float(spec.horizon)
        row = Row(
            name,
            spec.problem,
            spec.gamma,
            horizon,
            spec.optimum,
            spec.source,
            spec.evaluator,
            spec.rollouts,
            spec.restarts,
            dict(spec.gdice),
        )
        configs = []
        for changes in (dict(row.gdice), {**row.gdice, **budget}):
            for key in ("iterations", "samples"):
                cap = getattr(study.caps, key)
                if cap is not None:
                    changes[f"ce_{key}"] = min(changes.get(f"ce_{key}", getattr(base, f"ce_{key}")), cap)
            changes["ce_elites"] = min(
                changes.get("ce_elites", base.ce_elites), changes.get("ce_samples", base.ce_samples)
            )
            try:  # a graph that starts at full size (G-DICE's) follows the row's num_nodes (PlannerConfig.replace)
                configs.append(base.replace(**changes))
            except Exception as exc:  # noqa: BLE001  (re-raised with the row's name)
                raise ValueError(f"study.rows.{name}.gdice: {exc}") from None
        rows.append((row, *configs))
    return rows


def fraction_of_optimum(value: float, optimum: float, random_mean: float) -> float:
    """``1 - (V* - V) / |V*|``; with ``V* = 0``, the shortfall over the random controllers' shortfall."""
    scale = abs(optimum) if optimum != 0 else abs(optimum - random_mean)
    return 1.0 - (optimum - value) / scale if scale > 0 else float(value >= optimum)


def uniform_controllers(config: PlannerConfig, env: TabularDecPOSMDP, count: int, generator: torch.Generator):
    """Controllers from G-DICE's initial (uniform) distributions: the random baseline of the same graph."""
    a, nn = env.num_agents, config.num_nodes
    mask = layered_mask(nn, config.layer_width).to(torch.float64)
    nxt = (mask / mask.sum(-1, keepdim=True))[None, :, None, :].expand(a, nn, env.num_obs, nn).contiguous()
    act = torch.full((a, nn, env.num_actions), 1.0 / env.num_actions, dtype=torch.float64)
    return sample_controllers(act, nxt, count, generator)


def _search(row: Row, config: PlannerConfig, env: TabularDecPOSMDP, restarts: int, seed: int, progress: bool) -> dict:
    """Run G-DICE ``restarts`` times (scores: exact, or ``row.rollouts`` rollouts with ``ce_rollouts`` set to it);
    the best controller by exact value, with wall and CPU seconds per run."""
    scorer = ExactScorer(env) if row.evaluator == "exact" else RolloutScorer(env)
    if row.evaluator != "exact":
        config = dataclasses.replace(config, ce_rollouts=row.rollouts)
    runs, values, walls, cpus = [], [], [], []
    for r in range(restarts):
        wall, cpu = time.perf_counter(), time.process_time()
        res = plan(scorer, config, seed=stream_seed(seed, "restart", r), progress=progress)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
        runs.append(res)
        values.append(exact_value(env, res.best).item())
    best = runs[max(range(restarts), key=values.__getitem__)]
    return {"best": best, "values": values, "wall": walls, "cpu": cpus}


def _solve(
    row: Row, env: TabularDecPOSMDP, study: BenchmarkStudy, seed: int, optimum: float | None, random_mean: float
) -> tuple[dict, object]:
    """``solve`` on the row with ``study.solve`` (capped by ``study.caps``): its table entry and controller."""
    kwargs = dict(study.solve)
    defaults = PlannerConfig()
    for cap, keys in (
        ("iterations", ("ce_iterations",)),
        ("samples", ("ce_samples",)),
        ("restarts", ("restarts", "layered_restarts", "jesp_restarts", "ascent_starts")),
    ):
        limit = getattr(study.caps, cap)
        if limit is not None:
            for key in keys:
                current = kwargs.get(key, getattr(defaults, key, None))
                kwargs[key] = limit if current is None else min(int(current), limit)
    if "ce_samples" in kwargs:
        kwargs["ce_elites"] = min(kwargs.get("ce_elites", defaults.ce_elites), kwargs["ce_samples"])
    cpu = time.process_time()
    found = solve(env, row.horizon, row.gamma, seed=stream_seed(seed, "solve"), threads=study.threads, **kwargs)
    cpu = time.process_time() - cpu
    frac = None if optimum is None else fraction_of_optimum(found.value, optimum, random_mean)
    return {
        "value": found.value,
        "fraction_of_optimum": frac,
        "meets_99": None if frac is None else bool(frac >= 0.99 - 1e-12),
        "bound": found.bound,
        "gap": found.gap,
        "proven": found.proven,
        "bounds": found.bounds._asdict(),
        "seconds": found.seconds,
        "cpu_seconds": cpu,
        "nodes": found.controller.num_nodes,
        "restarts": found.restarts,
        "budget_ended": found.budget_ended,
        "settings": kwargs,
    }, found.controller


def solve_row(
    row: Row, config: PlannerConfig, paper: PlannerConfig, study: BenchmarkStudy, seed: int, progress: bool
) -> tuple[dict, object, list, object]:
    """One row of the table, G-DICE's best controller and its learning curve, and solve's controller."""
    env = TabularDecPOSMDP.from_problem(row.problem, gamma=row.gamma, horizon=row.horizon)
    restarts = row.restarts if study.caps.restarts is None else min(row.restarts, study.caps.restarts)
    found = _search(row, config, env, restarts, seed, progress)
    at_paper = _search(
        row, paper, env, 1, stream_seed(seed, "paper settings"), progress
    )  # one run at N_s = 100, N_k = 100, timed
    value = exact_value(env, found["best"].best).item()
    rand = exact_value(env, uniform_controllers(config, env, study.random_controllers, torch_stream(seed, "random")))
    rand_mean = rand.mean().item()
    exhaustive, searched = (None, None)
    if row.horizon == 2:
        exhaustive, searched = exhaustive_optimum(env, 2)
    optimum, source = row.optimum, row.source
    if optimum is None and exhaustive is not None:
        optimum, source = exhaustive, f"exhaustive search over all {searched} deterministic joint policies (this run)"
    frac = None if optimum is None else fraction_of_optimum(value, optimum, rand_mean)
    solved, solved_controller = _solve(row, env, study, seed, optimum, rand_mean)
    table = {
        "problem": row.problem,
        "states": env.num_states,
        "gamma": row.gamma,
        "horizon": "inf" if row.horizon == math.inf else int(row.horizon),
        "evaluator": row.evaluator,
        "gdice_value": value,
        "restart_values": found["values"],
        "optimum": optimum,
        "optimum_source": source,
        "published_optimum": row.optimum,
        "exhaustive_optimum_h2": exhaustive,
        "fraction_of_optimum": frac,
        "meets_95": None if frac is None else bool(frac >= 0.95 - 1e-12),
        "gap_closed": None if optimum is None or optimum == rand_mean else (value - rand_mean) / (optimum - rand_mean),
        "random_controller_mean": rand_mean,
        "random_controller_stderr": (rand.std() / math.sqrt(rand.numel())).item(),
        "seconds_per_run": found["wall"],
        "cpu_seconds_per_run": found["cpu"],
        "controllers_per_run": config.ce_iterations * config.ce_samples,
        "settings": {**dataclasses.asdict(config), "restarts": restarts},
        "paper_budget": {
            "samples": paper.ce_samples,
            "iterations": paper.ce_iterations,
            "value": at_paper["values"][0],
            "seconds": at_paper["wall"][0],
            "cpu_seconds": at_paper["cpu"][0],
        },
        "solve": solved,
    }
    return table, found["best"].best, found["best"].history["best_sampled"], solved_controller


def run(settings: DPOMDPBenchmarks, run_dir: Path) -> dict:
    study = settings.study
    rows = build_rows(study, settings.planner)  # every row's planner built before any work
    if study.only is not None:
        rows = [r for r in rows if r[0].name in set(study.only)]
    set_threads(study.threads)  # torch and the rollout engine
    table, curves = {}, {}
    for row, config, paper in rows:
        entry, controller, curve, solved = solve_row(row, config, paper, study, settings.seed, settings.progress)
        controller.save(run_dir / "controllers" / f"{row.name}.safetensors")
        solved.save(run_dir / "controllers" / f"{row.name}_solve.safetensors")
        table[row.name], curves[row.name] = entry, curve
        opt = "n/a" if entry["optimum"] is None else f"{entry['optimum']:.4f}"
        frac = "" if entry["fraction_of_optimum"] is None else f" ({100 * entry['fraction_of_optimum']:.1f} % of it)"
        print(
            f"{row.name}: G-DICE {entry['gdice_value']:.4f}, optimum {opt}{frac}, random "
            f"{entry['random_controller_mean']:.3f}; {max(entry['seconds_per_run']):.1f} s wall / "
            f"{max(entry['cpu_seconds_per_run']):.1f} s CPU per run; paper budget: "
            f"{entry['paper_budget']['value']:.4f} in {entry['paper_budget']['seconds']:.1f} s wall / "
            f"{entry['paper_budget']['cpu_seconds']:.1f} s CPU; solve {entry['solve']['value']:.4f} "
            f"(bound {entry['solve']['bound']:.4f}, gap {100 * entry['solve']['gap']:.2f} %) in "
            f"{entry['solve']['cpu_seconds']:.1f} s CPU",
            flush=True,
        )
    _plot(table, run_dir / "dpomdp_benchmarks.png")
    atomic_write_text(run_dir / "table.md", markdown_table(table))
    print(
        f"wrote {run_dir / 'metrics.json'}, {run_dir / 'table.md'}, {run_dir / 'dpomdp_benchmarks.png'} and "
        f"{run_dir / 'controllers'}",
        flush=True,
    )
    scored = [e["meets_95"] for e in table.values() if e["meets_95"] is not None]
    solved = [e["solve"]["meets_99"] for e in table.values() if e["solve"]["meets_99"] is not None]
    return {
        "rows": table,
        "rows_scored": len(scored),
        "rows_meeting_95": sum(scored),
        "rows_missing_95": [n for n, e in table.items() if e["meets_95"] is False],
        "solve_rows_meeting_99": sum(solved),
        "solve_rows_missing_99": [n for n, e in table.items() if e["solve"]["meets_99"] is False],
    }


def markdown_table(table: dict) -> str:
    """The table for people: one line per row."""
    header = (
        "| row | S | gamma | h | optimum | solve | % of optimum | bound | gap | proven | CPU s | nodes | G-DICE | % of optimum "
        "| gap closed | random mean | wall s / CPU s per run | paper budget: value, wall s / CPU s |"
    )
    lines = [header, "|" + " --- |" * 18]
    for name, e in table.items():
        opt = "n/a" if e["optimum"] is None else f"{e['optimum']:.4f}"
        frac = (
            "n/a"
            if e["fraction_of_optimum"] is None
            else (f"{100 * e['fraction_of_optimum']:.1f}" + ("" if e["meets_95"] else " (misses 95 %)"))
        )
        gap = "n/a" if e["gap_closed"] is None else f"{e['gap_closed']:.3f}"
        sv = e["solve"]
        s_frac = (
            "n/a"
            if sv["fraction_of_optimum"] is None
            else (f"{100 * sv['fraction_of_optimum']:.1f}" + ("" if sv["meets_99"] else " (misses 99 %)"))
        )
        lines.append(
            f"| {name} | {e['states']} | {e['gamma']} | {e['horizon']} | {opt} | {sv['value']:.4f} | {s_frac} "
            f"| {sv['bound']:.4f} | {100 * sv['gap']:.2f} % | {'yes' if sv['proven'] else 'no'} "
            f"| {sv['cpu_seconds']:.1f} | {sv['nodes']} "
            f"| {e['gdice_value']:.4f} | {frac} "
            f"| {gap} | {e['random_controller_mean']:.3f} | {max(e['seconds_per_run']):.1f} / "
            f"{max(e['cpu_seconds_per_run']):.1f} | {e['paper_budget']['value']:.4f}, "
            f"{e['paper_budget']['seconds']:.1f} / {e['paper_budget']['cpu_seconds']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def _plot(table: dict, path: Path) -> None:
    names = list(table)
    fig, (ax, ax_t) = plt.subplots(
        1, 2, figsize=(12, 0.32 * len(names) + 1.6), sharey=True, gridspec_kw={"width_ratios": [3, 2]}
    )
    y = range(len(names))
    frac = [table[n]["fraction_of_optimum"] for n in names]
    gap = [table[n]["gap_closed"] for n in names]
    colors = ["0.7" if f is None else ("C2" if f >= 0.95 - 1e-12 else "C3") for f in frac]
    ax.barh(y, [0 if f is None else max(f, 0.0) for f in frac], color=colors, label="G-DICE")
    solved = [table[n]["solve"]["fraction_of_optimum"] for n in names]
    ax.scatter(
        [float("nan") if f is None else max(f, 0.0) for f in solved],
        y,
        marker="D",
        s=18,
        color="C0",
        zorder=4,
        label="solve",
    )
    ax.scatter(
        [g if g is not None else float("nan") for g in gap],
        y,
        marker="|",
        s=120,
        color="k",
        zorder=3,
        label="share of the random-to-optimum gap closed",
    )
    for i, f in enumerate(frac):
        label = "no published optimum" if f is None else f"{100 * f:.1f} %"
        ax.text(0.01 if f is None else max(f, 0.0) + 0.01, i, label, va="center", fontsize=7, color="0.2")
    ax.axvline(0.95, color="k", ls="--", lw=1, label="95 % of the optimum")
    ax.set_yticks(list(y), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 1.15)
    ax.set_xlabel("value as a fraction of the optimum (bars: G-DICE, green >= 95 %, red below; diamonds: solve)")
    ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False)
    ax_t.barh(
        y,
        [table[n]["paper_budget"]["cpu_seconds"] for n in names],
        color="C0",
        label="CPU s, one run at the paper budget",
    )
    ax_t.scatter(
        [table[n]["paper_budget"]["seconds"] for n in names], y, marker="x", color="k", label="wall s, same run"
    )
    ax_t.axvline(120, color="C3", ls=":", lw=1, label="2-minute floor")
    ax_t.set_xscale("log")
    ax_t.set_xlabel("seconds per G-DICE run at N_s = 100, N_k = 100")
    ax_t.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False)
    fig.suptitle("solve and G-DICE on the shipped .dpomdp benchmarks, exact values of the best controllers", y=1.02)
    fig.tight_layout()
    save_figure(fig, path)
