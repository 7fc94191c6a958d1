"""G-DICE on package delivery (ICRA 2016): value against iteration, a sweep over alpha, and baselines.

G-DICE searches one finite-state controller that both robots run (as the reference study did;
``study.shared_controller``), scoring each sample by ``study.rollouts`` Monte Carlo rollouts; the
best controller is re-evaluated on ``study.reeval_rollouts`` independent rollouts. Two G-DICE runs
are reported: the paper's cold start (``planner``, uniform initial distributions; also the alpha
sweep) and "G-DICE seeded with the hand-written policy" (``planner`` overridden by
``study.seeded``: initial distributions ``(1 - init_weight) * uniform + init_weight * greedy``).
Baselines: Monte Carlo search over as many uniformly random controllers as the cold G-DICE samples,
the mean of random controllers, and the hand-written greedy controller. Writes ``metrics.json``,
``value_vs_iteration.png`` (cold), ``value_vs_iteration_seeded.png``, ``alpha_sweep.png``,
``baselines.png`` and the best joint controllers ``best_controller.safetensors`` (seeded) and
``best_controller_cold.safetensors`` (load with ``decpomdp.JointController.load``).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig

from decpomdp import GDICEConfig, JointController, MonteCarloEvaluator, gdice, monte_carlo_search, random_controllers
from decpomdp.core import DecPOSMDP
from decpomdp.domains import SharedControllerEvaluator, rollout_counters, shared
from decpomdp.policies import package_delivery_greedy
from experiments.common import save_figure

PAPER = {"gdice_best_sampled": 14.44, "mmcs": 4.53, "monte_carlo_search": 2.07}


def search_setup(env: DecPOSMDP, rollouts: int, shared_controller: bool):
    """(evaluator, agents searched, to_joint) for a team that shares one controller or not."""
    if shared_controller:
        return SharedControllerEvaluator(env, rollouts), 1, lambda c: shared(c, env.num_agents)
    return MonteCarloEvaluator(env, rollouts), env.num_agents, lambda c: c


def score(env: DecPOSMDP, controller: JointController, rollouts: int, seed: int) -> dict[str, Any]:
    """Mean return +- stderr over ``rollouts`` and the mean (+- stderr) of every per-rollout counter."""
    returns, counters = rollout_counters(env, controller, rollouts, torch.Generator().manual_seed(seed))
    out: dict[str, Any] = {"value": float(returns.mean()), "stderr": float(returns.std() / rollouts**0.5)}
    for key, value in counters.items():
        value = value.to(torch.float64)
        out[f"{key}_per_rollout"] = float(value.mean())
        out[f"{key}_stderr"] = float(value.std() / rollouts**0.5)
    return out


def run_gdice(
    env, config: GDICEConfig, study, seed: int, progress: bool, init: JointController | None = None
) -> tuple[Any, JointController, float]:
    """One G-DICE run; returns (result, best joint controller, seconds).

    ``init`` warm-starts the search (weight ``config.init_weight``): a one-agent controller when
    ``study.shared_controller`` is true (see :func:`seed_controller`), else a joint controller.
    """
    evaluator, agents, to_joint = search_setup(env, int(study.rollouts), bool(study.shared_controller))
    tic = time.perf_counter()
    result = gdice(evaluator, agents, env.num_actions, env.num_obs, config, seed=seed, init=init, progress=progress)
    return result, to_joint(result.best), time.perf_counter() - tic


def seed_controller(policy: JointController, shared_controller: bool) -> JointController:
    """The warm start G-DICE searches from: agent 0's FSC of ``policy`` for a shared controller, else all of it."""
    if not shared_controller:
        return policy
    return JointController(policy.action[:, :1].clone(), policy.next_node[:, :1].clone())


def mode_controller(action_probs, next_probs) -> JointController:
    """The most likely controller (K = 1) of G-DICE's distributions (A, Nn, |MA|) and (A, Nn, O, Nn)."""
    return JointController(action_probs.argmax(-1)[None], next_probs.argmax(-1)[None])


def run_seeded(env, config: GDICEConfig, study, policy: JointController, seed: int, progress: bool):
    """G-DICE seeded with ``policy`` (settings: ``config`` overridden by ``study.seeded``): (result, best, score).

    The best sampled controller is a maximum over noisy scores, so the final distributions' most
    likely controller is a second candidate: both are scored on ``study.select_rollouts`` rollouts,
    the better one is kept, and its reported value comes from ``study.reeval_rollouts`` further
    independent rollouts (so the selection does not bias it).
    """
    seeded_cfg = dataclasses.replace(config, **dict(study.seeded))
    shared_controller = bool(study.shared_controller)
    result, best, seconds = run_gdice(env, seeded_cfg, study, seed, progress, init=seed_controller(policy, shared_controller))
    mode = mode_controller(result.action_probs, result.next_probs)
    candidates = {"best_sampled": best, "mode": shared(mode, env.num_agents) if shared_controller else mode}
    selection = {name: score(env, ctrl, int(study.select_rollouts), seed + 20)["value"] for name, ctrl in candidates.items()}
    chosen = max(selection, key=selection.get)
    entry = {"init_weight": seeded_cfg.init_weight, "planner": dataclasses.asdict(seeded_cfg),
             "best_sampled": result.best_value, "seconds": seconds, "selected": chosen, "selection_values": selection,
             **score(env, candidates[chosen], int(study.reeval_rollouts), seed + 10)}
    return result, candidates[chosen], entry


def run_baselines(env, config: GDICEConfig, study, seed: int) -> dict[str, Any]:
    """Monte Carlo search with G-DICE's sample budget, and the mean of uniformly random controllers."""
    evaluator, agents, to_joint = search_setup(env, int(study.rollouts), bool(study.shared_controller))
    budget = config.iterations * config.samples
    tic = time.perf_counter()
    mcs = monte_carlo_search(evaluator, agents, env.num_actions, env.num_obs, config.num_nodes, budget, seed=seed)
    seconds = time.perf_counter() - tic
    rand = random_controllers(int(study.random_controllers), agents, config.num_nodes, env.num_actions, env.num_obs,
                              torch.Generator().manual_seed(seed + 1))
    values, _ = evaluator(rand, torch.Generator().manual_seed(seed + 2))
    return {
        "monte_carlo_search": {"budget": budget, "best_sampled": mcs.best_value, "seconds": seconds,
                               **score(env, to_joint(mcs.best), int(study.reeval_rollouts), seed + 3)},
        "random": {"controllers": len(values), "value": float(values.mean()),
                   "stderr": float(values.std() / len(values) ** 0.5)},
    }


def bar_figure(entries: dict[str, dict[str, float]], title: str, reference: dict[str, float] | None = None) -> plt.Figure:
    """Bar chart of value +- stderr per policy (optionally with dashed reference lines)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    names = list(entries)
    ax.bar(names, [entries[n]["value"] for n in names], yerr=[entries[n]["stderr"] for n in names], capsize=4,
           color=["tab:blue", "tab:orange", "tab:green", "tab:gray", "tab:purple"][: len(names)])
    for label, value in (reference or {}).items():
        ax.axhline(value, ls="--", lw=1, color="k", alpha=0.5)
        ax.text(-0.45, value, label, va="bottom", ha="left", fontsize=8)
    ax.set_ylim(top=1.1 * max([ax.get_ylim()[1], *(reference or {}).values()]))
    ax.set_ylabel("discounted return (mean +- s.e.)")
    ax.set_title(title)
    plt.setp(ax.get_xticklabels(), rotation=20, ha="right")
    fig.tight_layout()
    return fig


def history_figure(history: dict[str, list[float]], title: str) -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    its = range(1, len(history["best"]) + 1)
    ax.plot(its, history["best"], label="best sampled so far")
    ax.plot(its, history["iteration_best"], label="iteration best", alpha=0.7)
    ax.plot(its, history["iteration_mean"], label="iteration mean", alpha=0.7)
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("value (Monte Carlo estimate)")
    ax.set_title(title)
    ax.legend()
    return fig


def run(cfg: DictConfig, run_dir: Path) -> dict:
    study, seed = cfg.study, int(cfg.seed)
    torch.set_num_threads(int(study.threads))  # small tensors: one thread per job is fastest on shared cores
    env = instantiate(cfg.domain)
    config: GDICEConfig = instantiate(cfg.planner)
    reeval = int(study.reeval_rollouts)

    result, best, seconds = run_gdice(env, config, study, seed, bool(cfg.progress))
    best.save(run_dir / "best_controller_cold.safetensors")
    gdice_score = {"best_sampled": result.best_value, "seconds": seconds, **score(env, best, reeval, seed + 10)}
    save_figure(history_figure(result.history, "G-DICE on package delivery"), run_dir / "value_vs_iteration.png")
    seeded, seeded_best, seeded_score = run_seeded(env, config, study, package_delivery_greedy(), seed + 500,
                                                   bool(cfg.progress))
    seeded_best.save(run_dir / "best_controller.safetensors")
    save_figure(history_figure(seeded.history, "G-DICE seeded with the hand-written policy, package delivery"),
                run_dir / "value_vs_iteration_seeded.png")

    sweep = {}
    for k, alpha in enumerate(study.alpha_sweep):
        sweep_cfg = dataclasses.replace(config, alpha=float(alpha), iterations=int(study.sweep_iterations))
        res, ctrl, secs = run_gdice(env, sweep_cfg, study, seed + 100 + k, bool(cfg.progress))
        sweep[str(alpha)] = {"alpha": float(alpha), "history_best": res.history["best"], "best_sampled": res.best_value,
                             "seconds": secs, **score(env, ctrl, reeval, seed + 200 + k)}
    save_figure(_sweep_figure(sweep), run_dir / "alpha_sweep.png")

    baselines = run_baselines(env, config, study, seed + 300)
    greedy = score(env, package_delivery_greedy(), reeval, seed + 400)
    entries = {"G-DICE seeded": seeded_score, "G-DICE": gdice_score, "greedy (hand)": greedy, "Monte Carlo search": baselines["monte_carlo_search"],
               "random": baselines["random"]}
    save_figure(bar_figure(entries, "Package delivery: re-evaluated values",
                           {"paper G-DICE 14.44": PAPER["gdice_best_sampled"], "paper MCS 2.07": PAPER["monte_carlo_search"]}),
                run_dir / "baselines.png")
    mcs_value = baselines["monte_carlo_search"]["value"]
    return {
        "domain": repr(env),
        "planner": dataclasses.asdict(config),
        "shared_controller": bool(study.shared_controller),
        "rollouts_per_evaluation": int(study.rollouts),
        "reeval_rollouts": reeval,
        "gdice": gdice_score,
        "gdice_history": result.history,
        "gdice_seeded": seeded_score,
        "gdice_seeded_history": seeded.history,
        "alpha_sweep": sweep,
        "baselines": {**baselines, "greedy": greedy},
        "paper": PAPER,
        "acceptance": {
            "gdice_at_least_14.4": gdice_score["value"] >= 14.4,
            "mcs_at_most_third_of_gdice": mcs_value <= gdice_score["value"] / 3,
            "seeded_gdice_at_least_14.4": seeded_score["value"] >= 14.4,
            "mcs_at_most_third_of_seeded_gdice": mcs_value <= seeded_score["value"] / 3,
        },
    }


def _sweep_figure(sweep: dict[str, dict[str, Any]]) -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for entry in sweep.values():
        ax.plot(range(1, len(entry["history_best"]) + 1), entry["history_best"],
                label=f"alpha = {entry['alpha']:g} (re-evaluated {entry['value']:.2f})")
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("best sampled value so far")
    ax.set_title("Package delivery: learning rate alpha")
    ax.legend(fontsize=8)
    return fig
