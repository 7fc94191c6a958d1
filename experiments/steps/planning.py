"""Planning steps: G-DICE runs, the cold-start planner, baselines and scores on independent rollouts.

Shared by the package-delivery, disaster-relief and mission experiments. A team either shares
one controller (every robot runs agent 0's FSC; searched as a one-agent controller) or gives each
robot its own (``study.shared_controller``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import torch

from decpomdp import GDICEConfig, JointController, MonteCarloEvaluator, gdice, monte_carlo_search, random_controllers
from decpomdp.core import DecPOSMDP
from decpomdp.domains import SharedControllerEvaluator, rollout_counters, shared
from decpomdp.search import PlannerConfig, PlannerResult, RolloutScorer, plan
from infra.streams import stream_seed, torch_stream


def search_setup(env: DecPOSMDP, rollouts: int, shared_controller: bool):
    """(evaluator, agents searched, to_joint) for a team that shares one controller or not."""
    if shared_controller:
        return SharedControllerEvaluator(env, rollouts), 1, lambda c: shared(c, env.num_agents)
    return MonteCarloEvaluator(env, rollouts), env.num_agents, lambda c: c


def score(env: DecPOSMDP, controller: JointController, rollouts: int, seed: int,
          backend: str | None = None) -> dict[str, Any]:
    """Mean return +- stderr over ``rollouts`` and the mean (+- stderr) of every per-rollout counter
    (``backend``: as in :func:`decpomdp.simulate`)."""
    returns, counters = rollout_counters(env, controller, rollouts, torch.Generator().manual_seed(seed),
                                         backend=backend)
    out: dict[str, Any] = {"value": float(returns.mean()), "stderr": float(returns.std() / rollouts**0.5)}
    for key, value in counters.items():
        value = value.to(torch.float64)
        out[f"{key}_per_rollout"] = float(value.mean())
        out[f"{key}_stderr"] = float(value.std() / rollouts**0.5)
    return out


def delivery_rates(entry: dict[str, float]) -> dict[str, float]:
    """Wrong deliveries per delivery and frames per inference, from a disaster-relief score entry's counters."""
    wrong, right = entry["wrong_per_rollout"], entry["delivered_per_rollout"]
    return {"wrong_rate": wrong / max(wrong + right, 1e-12),
            "mean_inference_frames": entry["inference_frames_per_rollout"] / max(entry["inferences_per_rollout"], 1e-12)}


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


def run_cold(env: DecPOSMDP, config: PlannerConfig, shared_controller: bool, seed: int, progress: bool,
             reeval_rollouts: int, init: JointController | None = None
             ) -> tuple[PlannerResult, JointController, dict[str, Any]]:
    """The cold-start planner, from scratch or from ``init`` (searched agents): (result, best joint controller,
    score entry).

    The entry holds the value re-evaluated on ``reeval_rollouts`` fresh rollouts (stream ``(seed, "reeval")``),
    the rollouts spent, and process CPU and wall seconds of the search.
    """
    scorer = RolloutScorer(env, shared=shared_controller)
    cpu, wall = time.process_time(), time.perf_counter()
    result = plan(scorer, config, seed=seed, progress=progress, init=init)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    best = scorer.team(result.best)
    entry = {"rollouts": result.rollouts, "nodes": result.best.num_nodes, "cpu_seconds": cpu, "seconds": wall,
             **score(env, best, reeval_rollouts, stream_seed(seed, "reeval"))}
    return result, best, entry


def paper_comparison(env: DecPOSMDP, preset: DecPOSMDP, config: GDICEConfig, rollouts: int, runs: int, seed: int,
                     reeval_rollouts: int, progress: bool) -> dict[str, Any]:
    """The paper's G-DICE (``config``), one controller shared by both robots, on ``env`` and on ``preset``.

    Runs ``runs`` seeds on each domain. The paper reports the best *sampled* value (a maximum over
    noisy ``rollouts``-rollout scores), so both that and the value re-evaluated on ``reeval_rollouts``
    fresh rollouts are kept, per run and averaged (mean and its standard error over the runs).
    """
    out: dict[str, Any] = {}
    for name, domain in (("this_domain", env), ("preset", preset)):
        sampled, values, stderrs = [], [], []
        for r in range(runs):
            res = gdice(SharedControllerEvaluator(domain, rollouts), 1, domain.num_actions, domain.num_obs, config,
                        seed=stream_seed(seed, "paper", name, r), progress=progress)
            entry = score(domain, shared(res.best, domain.num_agents), reeval_rollouts,
                          stream_seed(seed, "reeval", name, r))
            sampled.append(res.best_value)
            values.append(entry["value"])
            stderrs.append(entry["stderr"])
        spread = lambda xs: float(torch.tensor(xs).std() / len(xs) ** 0.5) if len(xs) > 1 else float("nan")  # noqa: E731
        out[name] = {"domain": repr(domain), "best_sampled": sampled, "values": values, "stderrs": stderrs,
                     "best_sampled_mean": sum(sampled) / runs, "best_sampled_stderr": spread(sampled),
                     "value": sum(values) / runs, "stderr": spread(values)}
    return out


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
    selection = {name: score(env, ctrl, int(study.select_rollouts), stream_seed(seed, "select"))["value"] for name, ctrl in candidates.items()}
    chosen = max(selection, key=selection.get)
    entry = {"init_weight": seeded_cfg.init_weight, "planner": dataclasses.asdict(seeded_cfg),
             "best_sampled": result.best_value, "seconds": seconds, "selected": chosen, "selection_values": selection,
             **score(env, candidates[chosen], int(study.reeval_rollouts), stream_seed(seed, "reeval"))}
    return result, candidates[chosen], entry


def run_baselines(env, config: GDICEConfig, study, seed: int) -> dict[str, Any]:
    """Monte Carlo search with G-DICE's sample budget, and the mean of uniformly random controllers."""
    evaluator, agents, to_joint = search_setup(env, int(study.rollouts), bool(study.shared_controller))
    budget = config.iterations * config.samples
    tic = time.perf_counter()
    mcs = monte_carlo_search(evaluator, agents, env.num_actions, env.num_obs, config.num_nodes, budget, seed=seed)
    seconds = time.perf_counter() - tic
    rand = random_controllers(int(study.random_controllers), agents, config.num_nodes, env.num_actions, env.num_obs,
                              torch_stream(seed, "random controllers"))
    values, _ = evaluator(rand, torch_stream(seed, "random scores"))
    return {
        "monte_carlo_search": {"budget": budget, "best_sampled": mcs.best_value, "seconds": seconds,
                               **score(env, to_joint(mcs.best), int(study.reeval_rollouts),
                                                        stream_seed(seed, "reeval", "monte carlo search"))},
        "random": {"controllers": len(values), "value": float(values.mean()),
                   "stderr": float(values.std() / len(values) ** 0.5)},
    }
