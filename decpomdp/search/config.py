"""Settings of the planner (:func:`decpomdp.search.plan`), checked when built: the cold-start planner's defaults, and
:func:`gdice_config`, the paper's G-DICE as a preset of the same settings."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from hbni_infra.checks import as_float, as_int

PHASES = ("ce", "ls")
RESULTS = ("duel", "best_sampled")
THRESHOLD_RULES = ("none", "paper", "capped")


NO_BUDGET = 2**62
"""A rollout budget that bounds nothing (a run bounded by its ``cycles``, as G-DICE's is)."""


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of the planner; defaults are the tuned cold-start planner (``docs/planner.md``), and
    :func:`gdice_config` gives the paper's G-DICE.

    The run cycles through ``phases`` until ``budget`` rollouts are spent, ``patience`` whole cycles
    in a row improved nothing, or ``cycles`` cycles ran. It starts from a ``start_nodes``-node controller
    found by a cold cross-entropy phase (or, without a ``ce`` phase, node 0 running MA 0).

    Attributes:
        phases: the cycle, a sequence of ``"ce"`` (cross-entropy phase) and ``"ls"`` (local search).
        budget: rollouts the whole run may spend (the run stops at the first step boundary past it).
        patience: whole cycles without an accepted improvement before the run stops.
        cycles: most whole cycles (0: no limit).
        num_nodes: most nodes per agent (the graph grows up to it).
        start_nodes: nodes of the cold start (the first cross-entropy phase searches over this many).
        grow_nodes: nodes added when local search lacks free nodes for a chain (0: never grow).
        ce_iterations: iterations of each cross-entropy phase.
        ce_samples: controllers sampled per iteration.
        ce_screen_rollouts: rollouts screening every sample (0: no racing, all on ``ce_rollouts``).
        ce_screen_keep: fraction of the screened samples scored again on ``ce_rollouts``.
        ce_rollouts: rollouts per contender (and per memory controller) in an iteration.
        ce_elites: N_b, elites per update.
        ce_memory: elites carried to the next iteration and re-scored there (0: no memory).
        ce_alpha: learning rate of the update, in (0, 1].
        ce_init_weight: weight of the incumbent in a warm phase's initial distributions, in [0, 1] (1: every
            first-iteration sample is the incumbent).
        ce_threshold: which elites update the distributions: ``"none"`` (the best ``ce_elites``), ``"paper"``
            (G-DICE's rule: only those at least as good as the previous iteration's worst elite) or
            ``"capped"`` (that threshold, never above this iteration's ``ce_elites``-th best).
        ce_result: how a cross-entropy phase ends: ``"duel"`` (its elites duel the incumbent on fresh
            rollouts) or ``"best_sampled"`` (the best controller it sampled, on the score it was sampled
            with, becomes the incumbent: G-DICE's result, a biased maximum).
        ce_injection_weight: weight of the uniform mixed into collapsed rows (0: no entropy injection).
        ce_injection_threshold: normalised entropy below which a row counts as collapsed.
        ce_injection_until: injection happens in the first this-fraction of a phase's iterations.
        layer_width: ``None`` for a free graph; ``W`` for a layered graph (finite horizons): node 0 is layer 0,
            then layers of ``W`` nodes (``num_nodes = 1 + W * (layers - 1)``); a node moves to the next layer
            only, and the last layer within itself. Cross-entropy phases only (no reactive phases).
        ce_reactive: cross-entropy phases search reactive controllers (tied edges: the next node depends on
            the last observation only, see :mod:`decpomdp.search.cross_entropy`) while the incumbent is
            reactive (the cold phase always); after local search has untied it, phases search whole graphs.
        ls_chain: longest chain insertion (0: single edits only).
        ls_team: also make every move with all agents at once (team moves; no effect with one agent).
        ls_copy: also move by copying one agent's whole graph onto another (no effect with one agent).
        ls_compose: also duel the racing survivors' changes merged into one move.
        ls_candidates: most moves raced per local-search step (chains are sampled beyond it).
        ls_candidates_first: moves raced by a step that follows an accepted move or opens a phase (at most
            ``ls_candidates``); a step after a failed one races ``ls_candidates``. While steps succeed, cheap steps
            climb fast; where improvements are rare, each step looks wider.
        ls_stages: racing stages ``(rollouts, keep)`` of a step; ``keep`` < 1 is a fraction, else a count.
        ls_patience: local-search steps in a row without improvement that end a local-search phase.
        ls_lookahead: before a local-search phase ends, the number of information-gathering insertions to take
            a local-search step from (:mod:`decpomdp.search.lookahead`; 0: none). Insertions are screened on
            twice the rollouts of the second racing stage (of the first if there is one). A lookahead costs about
            ``ls_lookahead + 1`` local-search steps, and starts only if the budget has that much left.
        ls_lookahead_loss: most value an insertion may lose, as a fraction of the incumbent's, to be looked through.
        duel_rollouts: fresh rollouts per controller when challengers duel the incumbent.
        duel_z: standard errors of the difference a challenger must win by.
        common_streams: common random numbers: the candidates of one racing stage, and the incumbent and
            challengers of a duel, run on the same random streams (rollout ``r`` of each draws from one stream),
            and a duel judges the rollout-by-rollout differences. Alike controllers then have alike returns, so
            the noise of a comparison comes from where they differ. Used where the scorer can
            (``scorer.common_streams``: the compiled engine); elsewhere every controller draws its own streams.
        edge_rate: least traversals per rollout for an edge to be edited.
        visit_rollouts: rollouts counting the incumbent's edge traversals.
    """

    phases: tuple[str, ...] = ("ce", "ls")
    budget: int = 40_000_000
    patience: int = 3
    cycles: int = 0
    num_nodes: int = 24
    start_nodes: int = 1
    grow_nodes: int = 4
    ce_iterations: int = 30
    ce_samples: int = 400
    ce_screen_rollouts: int = 10
    ce_screen_keep: float = 0.1
    ce_rollouts: int = 80
    ce_elites: int = 10
    ce_memory: int = 5
    ce_alpha: float = 0.2
    ce_init_weight: float = 0.7
    ce_reactive: bool = False
    ce_threshold: str = "none"
    ce_result: str = "duel"
    ce_injection_weight: float = 0.0
    ce_injection_threshold: float = 0.05
    ce_injection_until: float = 0.5
    layer_width: int | None = None
    ls_chain: int = 3
    ls_team: bool = True
    ls_compose: bool = True
    ls_copy: bool = True
    ls_candidates: int = 30_000
    ls_stages: tuple[tuple[int, float], ...] = field(default=((16, 0.05), (128, 0.1), (1024, 6)))
    ls_candidates_first: int = 10_000
    ls_patience: int = 3
    ls_lookahead: int = 3
    ls_lookahead_loss: float = 0.15
    duel_rollouts: int = 4000
    duel_z: float = 2.0
    common_streams: bool = True
    edge_rate: float = 0.01
    visit_rollouts: int = 500

    def __post_init__(self) -> None:
        phases = _sequence("phases", self.phases)
        if not phases or any(p not in PHASES for p in phases):
            raise ValueError(f"phases: expected a non-empty sequence of {PHASES}, got {self.phases!r}")
        object.__setattr__(self, "phases", phases)
        for name, low in (
            ("budget", 1),
            ("patience", 1),
            ("cycles", 0),
            ("num_nodes", 1),
            ("start_nodes", 1),
            ("grow_nodes", 0),
            ("ce_iterations", 1),
            ("ce_samples", 1),
            ("ce_screen_rollouts", 0),
            ("ce_rollouts", 2),
            ("ce_elites", 1),
            ("ce_memory", 0),
            ("ls_chain", 0),
            ("ls_candidates", 1),
            ("ls_candidates_first", 1),
            ("ls_patience", 1),
            ("ls_lookahead", 0),
            ("duel_rollouts", 2),
            ("visit_rollouts", 1),
        ):
            object.__setattr__(self, name, as_int(name, getattr(self, name), low))
        if self.ce_screen_rollouts == 1:
            raise ValueError("ce_screen_rollouts: expected 0 (no screening) or >= 2 (a standard error needs two)")
        if self.start_nodes > self.num_nodes:
            raise ValueError(f"start_nodes: expected <= num_nodes ({self.num_nodes}), got {self.start_nodes}")
        if self.ce_elites > self.ce_samples:
            raise ValueError(f"ce_elites: expected <= ce_samples ({self.ce_samples}), got {self.ce_elites}")
        if self.ce_memory > self.ce_elites:
            raise ValueError(f"ce_memory: expected <= ce_elites ({self.ce_elites}), got {self.ce_memory}")
        object.__setattr__(self, "ce_screen_keep", as_float("ce_screen_keep", self.ce_screen_keep, 0, 1, low_open=True))
        object.__setattr__(self, "ce_alpha", as_float("ce_alpha", self.ce_alpha, 0, 1, low_open=True))
        object.__setattr__(self, "ce_init_weight", as_float("ce_init_weight", self.ce_init_weight, 0, 1))
        object.__setattr__(self, "ls_lookahead_loss", as_float("ls_lookahead_loss", self.ls_lookahead_loss, 0, 1))
        for name in ("ce_injection_weight", "ce_injection_threshold", "ce_injection_until"):
            object.__setattr__(self, name, as_float(name, getattr(self, name), 0, 1))
        for name, options in (("ce_threshold", THRESHOLD_RULES), ("ce_result", RESULTS)):
            if getattr(self, name) not in options:
                raise ValueError(f"{name}: expected one of {options}, got {getattr(self, name)!r}")
        if self.layer_width is not None:
            w = as_int("layer_width", self.layer_width, 1)
            if self.num_nodes < 1 + w or (self.num_nodes - 1) % w:
                raise ValueError(
                    f"layer_width: expected W with num_nodes = 1 + W * k (k >= 1), got W = {w} "
                    f"for num_nodes = {self.num_nodes}"
                )
            if "ls" in self.phases or self.ce_reactive or self.start_nodes != self.num_nodes:
                raise ValueError(
                    "layer_width: a layered graph is searched by cross-entropy phases alone, over all "
                    "num_nodes nodes (phases=['ce'], ce_reactive=false, start_nodes=num_nodes)"
                )
            object.__setattr__(self, "layer_width", w)
        object.__setattr__(self, "duel_z", as_float("duel_z", self.duel_z, 0))
        object.__setattr__(self, "edge_rate", as_float("edge_rate", self.edge_rate, 0))
        object.__setattr__(self, "ls_stages", _stages(self.ls_stages))
        for name in ("ls_team", "ls_compose", "ls_copy", "ce_reactive", "common_streams"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name}: expected a bool, got {getattr(self, name)!r}")

    def ignored(self) -> set[str]:
        """The settings these settings make irrelevant: those of a phase the cycle never runs, the duel of a
        G-DICE run without local search, and injection settings without injection."""
        names = {f.name for f in dataclasses.fields(self)}
        out: set[str] = set()
        if "ce" not in self.phases:
            out |= {n for n in names if n.startswith("ce_")} | {"layer_width"}
        if "ls" not in self.phases:
            out |= {n for n in names if n.startswith("ls_")} | {"edge_rate", "visit_rollouts", "grow_nodes"}
            if self.ce_result == "best_sampled":
                out |= {"duel_rollouts", "duel_z"}
        if self.ce_injection_weight == 0:
            out |= {"ce_injection_threshold", "ce_injection_until"}
        return out

    def replace(self, **changes) -> "PlannerConfig":
        """A copy with ``changes``; a graph that starts at full size (``start_nodes == num_nodes``, as G-DICE's)
        keeps doing so when ``num_nodes`` changes alone."""
        if "num_nodes" in changes and "start_nodes" not in changes and self.start_nodes == self.num_nodes:
            changes["start_nodes"] = changes["num_nodes"]
        return dataclasses.replace(self, **changes)

    def fixed_steps(self) -> int | None:
        """The steps of a run that does only cross-entropy phases for a set number of ``cycles`` (G-DICE:
        ``ce_iterations`` of them), at most (the budget or ``patience`` may end it sooner); ``None`` for a run whose
        length its budget alone bounds."""
        if self.cycles and set(self.phases) == {"ce"}:
            return self.cycles * len(self.phases) * self.ce_iterations
        return None

    @property
    def paper_budget(self) -> int:
        """G-DICE's rollouts at the paper's package-delivery settings: 100 iterations x 100 samples x 80."""
        return 100 * 100 * 80


def gdice_config(**overrides) -> PlannerConfig:
    """The paper's G-DICE (Omidshafiei et al., ICRA 2016, Alg. 1) as planner settings: one cross-entropy phase of
    ``ce_iterations`` (N_k = 100) iterations over ``num_nodes`` (N_n = 13) nodes, ``ce_samples`` (N_s = 100)
    controllers each scored on ``ce_rollouts`` (80) rollouts with no racing, the best ``ce_elites`` (N_b = 10)
    above the previous worst elite updating with learning rate ``ce_alpha`` (0.1), no memory, no local search,
    and the best controller ever sampled as the result, every sample on its own random streams. ``overrides`` change
    any setting."""
    paper = dict(
        phases=("ce",),
        cycles=1,
        budget=NO_BUDGET,
        num_nodes=13,
        start_nodes=13,
        grow_nodes=0,
        ce_iterations=100,
        ce_samples=100,
        ce_screen_rollouts=0,
        ce_rollouts=80,
        ce_elites=10,
        ce_memory=0,
        ce_alpha=0.1,
        ce_init_weight=0.0,
        ce_threshold="paper",
        ce_result="best_sampled",
        common_streams=False,
    )
    paper.update(overrides)
    if "start_nodes" not in overrides:  # the paper's graph has num_nodes nodes from the start
        paper["start_nodes"] = paper["num_nodes"]
    return PlannerConfig(**paper)


def _sequence(name: str, value: object) -> tuple:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name}: expected a sequence, got {type(value).__name__} {value!r}")
    return tuple(value)


def _stages(value: object) -> tuple[tuple[int, float], ...]:
    """``ls_stages`` as ((rollouts >= 2, keep > 0), ...), non-empty."""
    stages = []
    for i, stage in enumerate(_sequence("ls_stages", value)):
        pair = _sequence(f"ls_stages[{i}]", stage)
        if len(pair) != 2:
            raise ValueError(f"ls_stages[{i}]: expected a pair (rollouts, keep), got {stage!r}")
        stages.append(
            (
                as_int(f"ls_stages[{i}].rollouts", pair[0], 2),
                as_float(f"ls_stages[{i}].keep", pair[1], 0, low_open=True),
            )
        )
    if not stages:
        raise ValueError("ls_stages: expected at least one (rollouts, keep) stage")
    return tuple(stages)
