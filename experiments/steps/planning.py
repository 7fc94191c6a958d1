"""Planning steps: planner runs (the cold-start planner or the paper's G-DICE, one stack), baselines and scores on
independent rollouts.

Shared by the package-delivery, disaster-relief and mission experiments. A team either shares
one controller (every robot runs agent 0's FSC; searched as a one-agent controller) or gives each
robot its own (``study.shared_controller``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import torch

from decpomdp import JointController, monte_carlo_search, random_controllers
from decpomdp.core import DecPOSMDP
from decpomdp.domains import rollout_counters
from decpomdp.search import PlannerConfig, PlannerResult, RolloutScorer, mean_stderr, plan
from experiments.schemas.blocks import BaselineStudy
from hbni_infra.streams import stream_seed, torch_generator, torch_stream


def score(
    env: DecPOSMDP, controller: JointController, rollouts: int, seed: int, backend: str | None = None
) -> dict[str, Any]:
    """Mean return +- stderr over ``rollouts`` and the mean (+- stderr) of every per-rollout counter
    (``backend``: as in :func:`decpomdp.simulate`)."""
    returns, counters = rollout_counters(env, controller, rollouts, torch_generator(seed), backend=backend)
    mean, se = mean_stderr(returns.flatten())
    out: dict[str, Any] = {"value": float(mean), "stderr": float(se)}
    for key, value in counters.items():
        mean, se = mean_stderr(value.flatten().to(torch.float64))
        out[f"{key}_per_rollout"], out[f"{key}_stderr"] = float(mean), float(se)
    return out


def delivery_rates(entry: dict[str, float]) -> dict[str, float]:
    """Wrong deliveries per delivery and frames per inference, from a disaster-relief score entry's counters."""
    wrong, right = entry["wrong_per_rollout"], entry["delivered_per_rollout"]
    return {
        "wrong_rate": wrong / max(wrong + right, 1e-12),
        "mean_inference_frames": entry["inference_frames_per_rollout"] / max(entry["inferences_per_rollout"], 1e-12),
    }


def run_planner(
    env: DecPOSMDP,
    config: PlannerConfig,
    shared_controller: bool,
    seed: int,
    progress: bool,
    reeval_rollouts: int,
    init: JointController | None = None,
) -> tuple[PlannerResult, JointController, dict[str, Any]]:
    """The planner (any preset: the cold-start planner, G-DICE), from scratch or from ``init`` (searched agents):
    (result, best joint controller, score entry).

    The entry holds the value re-evaluated on ``reeval_rollouts`` fresh rollouts (stream ``(seed, "reeval")``),
    the planner's own value of it (``planner_value``: its last duel mean, or for G-DICE the best sampled score, a
    biased maximum), the rollouts spent, and process CPU and wall seconds of the search.
    """
    scorer = RolloutScorer(env, shared=shared_controller)
    cpu, wall = time.process_time(), time.perf_counter()
    result = plan(scorer, config, seed=seed, progress=progress, init=init)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    best = scorer.team(result.best).named(env.action_names, env.obs_names)
    entry = {
        "rollouts": result.rollouts,
        "nodes": result.best.num_nodes,
        "cpu_seconds": cpu,
        "seconds": wall,
        "planner_value": result.value,
        **score(env, best, reeval_rollouts, stream_seed(seed, "reeval")),
    }
    return result, best, entry


def paper_comparison(
    env: DecPOSMDP, preset: DecPOSMDP, config: PlannerConfig, runs: int, seed: int, reeval_rollouts: int, progress: bool
) -> dict[str, Any]:
    """The paper's G-DICE (``config``), one controller shared by both robots, on ``env`` and on ``preset``.

    Runs ``runs`` seeds on each domain. The paper reports the best *sampled* value (a maximum over
    noisy ``config.ce_rollouts``-rollout scores), so both that and the value re-evaluated on ``reeval_rollouts``
    fresh rollouts are kept, per run and averaged (mean and its standard error over the runs).
    """
    out: dict[str, Any] = {}
    for name, domain in (("this_domain", env), ("preset", preset)):
        sampled, values, stderrs = [], [], []
        for r in range(runs):
            _, _, entry = run_planner(
                domain, config, True, stream_seed(seed, "paper", name, r), progress, reeval_rollouts
            )
            sampled.append(entry["planner_value"])
            values.append(entry["value"])
            stderrs.append(entry["stderr"])
        spread = lambda xs: float(mean_stderr(torch.tensor(xs))[1]) if len(xs) > 1 else float("nan")  # noqa: E731
        out[name] = {
            "domain": repr(domain),
            "best_sampled": sampled,
            "values": values,
            "stderrs": stderrs,
            "best_sampled_mean": sum(sampled) / runs,
            "best_sampled_stderr": spread(sampled),
            "value": sum(values) / runs,
            "stderr": spread(values),
        }
    return out


def seed_controller(policy: JointController, shared_controller: bool) -> JointController:
    """The warm start a planner searches from: agent 0's FSC of ``policy`` for a shared controller, else all of it."""
    if not shared_controller:
        return policy
    return JointController(policy.action[:, :1].clone(), policy.next_node[:, :1].clone())


def mode_controller(distributions: tuple[torch.Tensor, torch.Tensor]) -> JointController:
    """The most likely controller (K = 1) of cross-entropy distributions (A, Nn, |MA|) and (A, Nn, O, Nn)."""
    action_probs, next_probs = distributions
    return JointController(action_probs.argmax(-1)[None], next_probs.argmax(-1)[None])


def run_seeded(
    env: DecPOSMDP, config: PlannerConfig, study: BaselineStudy, policy: JointController, seed: int, progress: bool
):
    """G-DICE seeded with ``policy`` (settings: ``config`` overridden by ``study.seeded``): (result, best, score).

    The best sampled controller is a maximum over noisy scores, so the final distributions' most
    likely controller is a second candidate: both are scored on ``study.select_rollouts`` rollouts,
    the better one is kept, and its reported value comes from ``study.reeval_rollouts`` further
    independent rollouts (so the selection does not bias it).
    """
    seeded = config.replace(**study.seeded)
    shared_controller = study.shared_controller
    result, best, entry = run_planner(
        env,
        seeded,
        shared_controller,
        seed,
        progress,
        study.reeval_rollouts,
        init=seed_controller(policy, shared_controller),
    )
    mode = mode_controller(result.distributions)
    candidates = {
        "best_sampled": best,
        "mode": RolloutScorer(env, shared=shared_controller).team(mode).named(env.action_names, env.obs_names),
    }
    selection = {
        name: score(env, ctrl, study.select_rollouts, stream_seed(seed, "select"))["value"]
        for name, ctrl in candidates.items()
    }
    chosen = max(selection, key=selection.get)
    entry = {
        "init_weight": seeded.ce_init_weight,
        "planner": dataclasses.asdict(seeded),
        "best_sampled": entry["planner_value"],
        "seconds": entry["seconds"],
        "selected": chosen,
        "selection_values": selection,
        **score(env, candidates[chosen], study.reeval_rollouts, stream_seed(seed, "reeval")),
    }
    return result, candidates[chosen], entry


def run_baselines(env: DecPOSMDP, config: PlannerConfig, study: BaselineStudy, seed: int) -> dict[str, Any]:
    """Monte Carlo search with G-DICE's sample budget (``config``: its preset), and the mean of uniformly random
    controllers."""
    scorer = RolloutScorer(env, shared=study.shared_controller)
    budget, rollouts = config.ce_iterations * config.ce_samples, config.ce_rollouts
    tic = time.perf_counter()
    mcs = monte_carlo_search(scorer, num_nodes=config.num_nodes, budget=budget, rollouts=rollouts, seed=seed)
    seconds = time.perf_counter() - tic
    rand = random_controllers(
        study.random_controllers,
        num_agents=scorer.num_agents,
        num_nodes=config.num_nodes,
        num_actions=env.num_actions,
        num_obs=env.num_obs,
        generator=torch_stream(seed, "random controllers"),
    )
    values, _ = scorer(rand, rollouts, torch_stream(seed, "random scores"))
    mean, se = mean_stderr(values)
    return {
        "monte_carlo_search": {
            "budget": budget,
            "best_sampled": mcs.best_value,
            "seconds": seconds,
            **score(
                env,
                scorer.team(mcs.best),
                study.reeval_rollouts,
                stream_seed(seed, "reeval", "monte carlo search"),
            ),
        },
        "random": {"controllers": len(values), "value": float(mean), "stderr": float(se)},
    }
