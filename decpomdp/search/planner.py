"""The cold-start planner: cross-entropy over controller graphs (G-DICE) and local search, in turns.

From no controller at all (or from a warm-start controller ``init``), the run cycles through
``config.phases``:

* ``"ce"``: a cross-entropy phase (:mod:`decpomdp.search.cross_entropy`): cold (uniform over
  ``start_nodes`` nodes) the first time when there is no incumbent yet, later warm-started from the
  incumbent with weight ``ce_init_weight``; after ``ce_iterations`` iterations its elites duel the
  incumbent (:func:`~decpomdp.search.racing.duel`) and the winner becomes the incumbent. With
  ``ce_reactive``, a phase searches reactive controllers (tied edges) while the incumbent is reactive
  (the cold phase always): a reactive start, refined by whole-graph phases once local search unties it;
* ``"ls"``: local search (:mod:`decpomdp.search.local_search`) until ``ls_patience`` steps in a row
  find nothing; it grows the graph up to ``num_nodes`` nodes when it needs free nodes for a chain. Before
  the phase gives up, it looks through the ``ls_lookahead`` most informative insertions
  (:mod:`decpomdp.search.lookahead`): two-move improvements whose first move loses value alone.

The run stops at the first step boundary past ``budget`` rollouts, or after ``patience`` whole cycles
without an improvement. Every step draws from one generator seeded by ``seed``, and the budget is
counted in rollouts, so a run is reproducible whatever the machine's load. A checkpoint written after
any step (with the generator state and every phase's state) resumes to exactly the uninterrupted
result; it records what produced it and refuses any other run (:mod:`decpomdp.checkpoints`).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from tqdm.auto import tqdm

from hbni_infra.checks import as_int, as_seed
from decpomdp.budget import BudgetSpent
from decpomdp.checkpoints import load_checkpoint, read_count, read_history, read_number, save_checkpoint
from decpomdp.controller import JointController
from decpomdp.identity import describe
from decpomdp.search import cross_entropy, local_search, lookahead
from decpomdp.search.config import PHASES, PlannerConfig
from decpomdp.search.racing import duel
from decpomdp.search.scoring import Scorer
from hbni_infra.streams import torch_generator

_KIND = "decpomdp.PlannerCheckpoint"
_VERSION = 1
HISTORY = (
    "phase",
    "rollouts",
    "nodes",
    "value",
    "challenger_value",
    "accepted",
    "best_sampled",
    "mean",
    "kept",
    "threshold",
    "entropy",
)
_COUNTERS = ("cycle_position", "phase_step", "used", "idle_cycles", "gained", "cycles_done")


@dataclass
class PlannerResult:
    """Outcome of :func:`plan`.

    Attributes:
        best: the final incumbent (K = 1, searched agents).
        value, stderr: its mean and standard error in its last duel (fresh rollouts, but the duel
            that kept it is a selection: re-evaluate independently for an unbiased value). With
            ``ce_result="best_sampled"`` (G-DICE) the value is the best sampled score, a biased maximum, and the
            standard error is NaN.
        rollouts: rollouts spent.
        history: per step: ``phase`` (0 cross-entropy iteration, 1 local-search step), ``rollouts`` spent
            so far, ``nodes`` of the incumbent, ``value`` (the incumbent's duel mean after the step; NaN
            for a cross-entropy iteration that ends no phase), ``challenger_value`` (the best challenger's
            duel mean, or the best elite's score in a cross-entropy iteration) and ``accepted`` (1 if the
            incumbent changed); for a cross-entropy iteration also ``best_sampled`` (the best score sampled so far in
            the phase), ``mean`` (the samples' mean score), ``kept`` (elites used), ``threshold`` (the worst
            elite score) and ``entropy`` (the distributions' mean normalised entropy), NaN for other steps.
        distributions: the final ``(action_probs, next_probs)`` of the last cross-entropy phase (None without one).
    """

    best: JointController
    value: float
    stderr: float
    rollouts: int
    history: dict[str, list[float]]
    config: PlannerConfig = field(default_factory=PlannerConfig)
    distributions: tuple[torch.Tensor, torch.Tensor] | None = None


class _Run:
    """Everything a run carries between steps (what a checkpoint stores)."""

    def __init__(self) -> None:
        self.incumbent: JointController | None = None
        self.value = self.stderr = math.nan
        self.ce: cross_entropy.CrossEntropyState | None = None
        self.cycle_position = self.phase_step = self.used = self.idle_cycles = self.gained = self.cycles_done = 0
        self.distributions: tuple[torch.Tensor, torch.Tensor] | None = None
        self.history: dict[str, list[float]] = {k: [] for k in HISTORY}

    def record(self, phase: str, value: float, challenger_value: float, accepted: bool, info: dict[str, float]) -> None:
        for key, value in (
            ("phase", PHASES.index(phase)),
            ("rollouts", self.used),
            ("nodes", 0 if self.incumbent is None else self.incumbent.num_nodes),
            ("value", value),
            ("challenger_value", challenger_value),
            ("accepted", accepted),
        ):
            self.history[key].append(float(value))
        for key in HISTORY[6:]:
            self.history[key].append(float(info.get(key, math.nan)))

    def tensors(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        out = {"generator_state": generator.get_state()}
        if self.incumbent is not None:
            out.update(incumbent_action=self.incumbent.action, incumbent_next_node=self.incumbent.next_node)
        if self.ce is not None:
            out.update(
                ce_action_probs=self.ce.action_probs,
                ce_next_probs=self.ce.next_probs,
                ce_action_uniform=self.ce.action_uniform,
                ce_next_uniform=self.ce.next_uniform,
            )
            if self.ce.elites is not None:
                out.update(ce_elites_action=self.ce.elites.action, ce_elites_next_node=self.ce.elites.next_node)
            if self.ce.best is not None:
                out.update(ce_best_action=self.ce.best.action, ce_best_next_node=self.ce.best.next_node)
        if self.distributions is not None:
            out.update(last_action_probs=self.distributions[0], last_next_probs=self.distributions[1])
        return out

    def save(self, path: Path, fingerprint: dict, generator: torch.Generator) -> None:
        finite = lambda x: None if not math.isfinite(x) else x  # noqa: E731
        state = {name: getattr(self, name) for name in _COUNTERS}
        state.update(
            value=finite(self.value),
            stderr=finite(self.stderr),
            history={k: [finite(v) for v in values] for k, values in self.history.items()},
        )
        if self.ce is not None:
            state.update(ce_threshold=finite(self.ce.threshold), ce_best_value=finite(self.ce.best_value))
        save_checkpoint(path, _KIND, _VERSION, fingerprint, self.tensors(generator), state)

    @classmethod
    def load(cls, path: Path, fingerprint: dict, config: PlannerConfig, generator: torch.Generator) -> _Run:
        tensors, meta = load_checkpoint(path, _KIND, _VERSION, fingerprint)
        run = cls()
        limits = {
            "cycle_position": len(config.phases) - 1,
            "phase_step": max(config.ce_iterations, config.ls_patience),
            "used": 2**63,
            "idle_cycles": config.patience,
            "gained": 1,
            "cycles_done": 2**62,
        }
        for name in _COUNTERS:
            setattr(run, name, read_count(meta, name, path, limits[name]))
        run.value, run.stderr = (_nan_if_none(read_number(meta, name, path)) for name in ("value", "stderr"))
        history = meta.get("history")
        length = len(history["phase"]) if isinstance(history, dict) and isinstance(history.get("phase"), list) else -1
        run.history = read_history(meta, HISTORY, max(length, 0), path, none=math.nan)
        try:
            pair = lambda name: JointController(tensors[f"{name}_action"], tensors[f"{name}_next_node"])  # noqa: E731
            if "incumbent_action" in tensors:
                run.incumbent = pair("incumbent")
            if "ce_action_probs" in tensors:
                run.ce = cross_entropy.CrossEntropyState(
                    tensors["ce_action_probs"],
                    tensors["ce_next_probs"],
                    tensors["ce_action_uniform"],
                    tensors["ce_next_uniform"],
                )
                run.ce.elites = pair("ce_elites") if "ce_elites_action" in tensors else None
                run.ce.best = pair("ce_best") if "ce_best_action" in tensors else None
                run.ce.threshold = read_number(meta, "ce_threshold", path)
                run.ce.best_value = read_number(meta, "ce_best_value", path)
            if "last_action_probs" in tensors:
                run.distributions = (tensors["last_action_probs"], tensors["last_next_probs"])
            generator.set_state(tensors["generator_state"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"checkpoint: {str(path)!r} is inconsistent ({exc})") from None
        return run


def _check_arguments(scorer: Scorer, cfg: PlannerConfig, init: JointController | None) -> PlannerConfig:
    """Validate :func:`plan`'s scorer, config and warm-start controller; returns the config."""
    if not isinstance(cfg, PlannerConfig):
        raise TypeError(f"config: expected a PlannerConfig, got {type(cfg).__name__}")
    for name in ("num_agents", "num_actions", "num_obs"):
        as_int(f"scorer.{name}", getattr(scorer, name, None), 1)
    if not callable(scorer) or not callable(getattr(scorer, "visits", None)):
        raise TypeError(f"scorer: expected a Scorer (callable with a visits method), got {type(scorer).__name__}")
    _check_init(init, scorer, cfg)
    return cfg


def _check_init(init: JointController | None, scorer: Scorer, cfg: PlannerConfig) -> None:
    """Validate a warm-start controller against the searched agents' sizes and the graph's layers."""
    max_nodes = cfg.num_nodes
    if init is None:
        return
    if not isinstance(init, JointController):
        raise TypeError(f"init: expected a JointController, got {type(init).__name__}")
    k, a, nodes = init.action.shape
    if k != 1 or a != scorer.num_agents or init.num_obs != scorer.num_obs or nodes > max_nodes:
        raise ValueError(
            f"init: expected one controller of {scorer.num_agents} agents, at most {max_nodes} nodes "
            f"(config.num_nodes) and {scorer.num_obs} observations, got action {tuple(init.action.shape)}, "
            f"next_node {tuple(init.next_node.shape)}"
        )
    if bool((init.action >= scorer.num_actions).any()):
        raise ValueError(f"init: actions must lie in [0, {scorer.num_actions})")
    mask = cross_entropy.layered_mask(cfg.num_nodes, cfg.layer_width)
    rows = torch.arange(nodes)[None, None, :, None].expand_as(init.next_node)
    if not bool(mask[rows, init.next_node].all()):
        raise ValueError("init: transitions must respect the layered graph (config.layer_width)")


def _nan_if_none(value: float) -> float:
    """A saved ``None`` (read as -inf) stands for NaN, "not measured yet"."""
    return math.nan if value == -math.inf else value


def _ce_step(
    run: _Run, scorer: Scorer, cfg: PlannerConfig, generator: torch.Generator
) -> tuple[bool, float, float, bool, dict[str, float]]:
    """One cross-entropy iteration; at the phase's end its elites duel the incumbent (``ce_result="duel"``), or its
    best sample becomes the incumbent (``"best_sampled"``).

    Returns: (phase over, the incumbent's value after the phase or NaN, best elite score, incumbent replaced,
    the iteration's record).
    """
    if run.ce is None:
        nodes = cfg.start_nodes if run.incumbent is None else max(cfg.start_nodes, run.incumbent.num_nodes)
        weight = 0.0 if run.incumbent is None else cfg.ce_init_weight
        reactive = cfg.ce_reactive and (run.incumbent is None or cross_entropy.is_reactive(run.incumbent))
        run.ce = cross_entropy.start_state(
            run.incumbent,
            scorer.num_agents,
            nodes,
            scorer.num_actions,
            scorer.num_obs,
            weight,
            reactive=reactive,
            mask=cross_entropy.layered_mask(nodes, cfg.layer_width),
        )
    injecting = cfg.ce_injection_weight > 0 and run.phase_step < cfg.ce_injection_until * cfg.ce_iterations
    info = cross_entropy.iterate(
        run.ce,
        scorer,
        generator,
        samples=cfg.ce_samples,
        screen_rollouts=cfg.ce_screen_rollouts,
        screen_keep=cfg.ce_screen_keep,
        rollouts=cfg.ce_rollouts,
        elites=cfg.ce_elites,
        memory=cfg.ce_memory,
        alpha=cfg.ce_alpha,
        threshold_rule=cfg.ce_threshold,
        injection=cross_entropy.Injection(cfg.ce_injection_weight, cfg.ce_injection_threshold) if injecting else None,
        common=_common(scorer, cfg),
    )
    info["best_sampled"] = run.ce.best_value
    run.phase_step += 1
    if run.phase_step < cfg.ce_iterations:
        return False, math.nan, info["best"], False, info
    elites = run.ce.elites
    if cfg.ce_result == "best_sampled":  # G-DICE: the best controller sampled, on its sampled score
        accepted = run.incumbent is None or run.ce.best_value > run.value or math.isnan(run.value)
        if accepted:
            run.incumbent, run.value, run.stderr = run.ce.best, run.ce.best_value, math.nan
    elif run.incumbent is None or elites is None:  # the cold phase: its best elite on fresh rollouts
        pool = elites if elites is not None else run.ce.best
        mean, se = scorer(pool, cfg.duel_rollouts, generator)
        top = int(mean.argmax())
        run.incumbent, run.value, run.stderr = pool[top], float(mean[top]), float(se[top])
        accepted = True
    else:
        winner, mean, se = duel(
            scorer, run.incumbent, elites, cfg.duel_rollouts, cfg.duel_z, generator, _common(scorer, cfg)
        )
        accepted = winner is not None
        pick = 0 if winner is None else winner + 1
        run.value, run.stderr = float(mean[pick]), float(se[pick])
        if accepted:
            run.incumbent = elites[winner]
    run.distributions = (run.ce.action_probs, run.ce.next_probs)
    run.ce = None
    return True, run.value, info["best"], accepted, info


def _common(scorer: Scorer, cfg: PlannerConfig) -> bool:
    """Whether to race and duel on common random numbers: asked for, and the scorer can."""
    return cfg.common_streams and getattr(scorer, "common_streams", False)


def _ls_step(
    run: _Run, scorer: Scorer, cfg: PlannerConfig, generator: torch.Generator
) -> tuple[bool, float, float, bool, dict[str, float]]:
    """One local-search step.

    Returns: (phase over: ``ls_patience`` failures in a row, the incumbent's duel mean after the step, the best
    challenger's, accepted).
    """
    if run.incumbent is None:  # no cross-entropy phase: node 0 runs MA 0 forever
        run.incumbent = JointController(
            torch.zeros(1, scorer.num_agents, cfg.start_nodes, dtype=torch.long),
            torch.zeros(1, scorer.num_agents, cfg.start_nodes, scorer.num_obs, dtype=torch.long),
        )
    settings = dict(
        max_chain=cfg.ls_chain,
        max_nodes=cfg.num_nodes,
        grow_nodes=cfg.grow_nodes,
        candidates=cfg.ls_candidates if run.phase_step > 0 else min(cfg.ls_candidates_first, cfg.ls_candidates),
        stages=cfg.ls_stages,
        duel_rollouts=cfg.duel_rollouts,
        z=cfg.duel_z,
        edge_rate=cfg.edge_rate,
        visit_rollouts=cfg.visit_rollouts,
        team=cfg.ls_team,
        compose=cfg.ls_compose,
        copy=cfg.ls_copy,
        common=_common(scorer, cfg),
    )
    before = scorer.rollouts_used
    out = local_search.step(run.incumbent, scorer, generator, **settings)
    cost = scorer.rollouts_used - before  # a lookahead costs about ls_lookahead + 1 such steps
    left = cfg.budget - run.used - cost
    if (
        not out.accepted
        and run.phase_step + 1 >= cfg.ls_patience
        and 0 < cfg.ls_lookahead
        and left >= cost * (cfg.ls_lookahead + 1)
    ):
        screen = 2 * cfg.ls_stages[min(1, len(cfg.ls_stages) - 1)][0]
        width, loss = cfg.ls_lookahead, cfg.ls_lookahead_loss
        looked = lookahead.step(
            out.controller, scorer, generator, width=width, loss=loss, screen_rollouts=screen, **settings
        )
        out = looked if looked.accepted else out  # else the step's own duel values stand
    run.incumbent = out.controller
    run.value = out.challenger_value if out.accepted else out.incumbent_value
    run.phase_step = 0 if out.accepted else run.phase_step + 1
    return run.phase_step >= cfg.ls_patience, run.value, out.challenger_value, out.accepted, {}


def plan(
    scorer: Scorer,
    config: PlannerConfig | None = None,
    seed: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: int = 1,
    progress: bool = False,
    init: JointController | None = None,
) -> PlannerResult:
    """Plan a controller from scratch, or from ``init`` (see the module doc).

    Args:
        scorer: scores controllers of the searched agents (:class:`~decpomdp.search.scoring.RolloutScorer`
            or :class:`~decpomdp.search.scoring.ExactScorer`).
        config: the settings (default :class:`PlannerConfig`).
        seed: seeds the one generator of the run.
        checkpoint: file written every ``checkpoint_every`` steps and at the end; if it exists, the run
            resumes from it. It records what produced it (sizes, scorer and problem, config, seed);
            resuming it with any of them different raises a ``ValueError`` naming the fields.
        progress: show a progress bar over the rollout budget.
        init: the first incumbent (K = 1, the searched agents, at most ``config.num_nodes`` nodes), for
            instance a plan of a related problem; ``None`` starts from no controller. Its first phase is
            then warm: cross-entropy starts from it with weight ``ce_init_weight``, local search edits it.

    Inside a :class:`~decpomdp.budget.Budget` that ends during a step, the run returns the incumbent of its last
    complete step (the checkpoint, if any, stays at that step); with no incumbent yet, the
    :class:`~decpomdp.budget.BudgetSpent` propagates.
    """
    cfg = _check_arguments(scorer, PlannerConfig() if config is None else config, init)
    seed, checkpoint_every = as_seed("seed", seed), as_int("checkpoint_every", checkpoint_every, 1)
    generator = torch_generator(seed)
    fingerprint = {
        "sizes": {name: getattr(scorer, name) for name in ("num_agents", "num_actions", "num_obs")},
        "problem": describe(scorer),
        "config": asdict(cfg),
        "seed": seed,
        "init": None if init is None else describe(init),
    }
    path = None if checkpoint is None else Path(checkpoint)
    if path is not None and path.exists():
        run = _Run.load(path, fingerprint, cfg, generator)
    else:
        run = _Run()
        run.incumbent = None if init is None else JointController(init.action.clone(), init.next_node.clone())
    steps = {"ce": _ce_step, "ls": _ls_step}
    bar = tqdm(
        total=cfg.budget, initial=min(run.used, cfg.budget), disable=not progress, desc="planner", unit="rollout"
    )
    while (
        run.used < cfg.budget and run.idle_cycles < cfg.patience and not (cfg.cycles and run.cycles_done >= cfg.cycles)
    ):
        before = scorer.rollouts_used
        phase = cfg.phases[run.cycle_position]
        try:
            over, value, challenger_value, accepted, info = steps[phase](run, scorer, cfg, generator)
        except BudgetSpent:
            bar.close()
            if run.incumbent is None:
                raise
            return PlannerResult(run.incumbent, run.value, run.stderr, run.used, run.history, cfg, run.distributions)
        spent = scorer.rollouts_used - before
        run.used += spent
        run.record(phase, value, challenger_value, accepted, info)
        run.gained = int(run.gained or accepted)
        if over:
            run.phase_step = 0
            run.cycle_position = (run.cycle_position + 1) % len(cfg.phases)
            if run.cycle_position == 0:
                run.idle_cycles = 0 if run.gained else run.idle_cycles + 1
                run.gained = 0
                run.cycles_done += 1
        bar.update(min(spent, max(cfg.budget - bar.n, 0)))
        bar.set_postfix(phase=phase, value=f"{run.value:.4g}", nodes=run.incumbent.num_nodes if run.incumbent else 0)
        if path is not None and (len(run.history["phase"]) % checkpoint_every == 0):
            run.save(path, fingerprint, generator)
    bar.close()
    if path is not None:
        run.save(path, fingerprint, generator)
    return PlannerResult(run.incumbent, run.value, run.stderr, run.used, run.history, cfg, run.distributions)
