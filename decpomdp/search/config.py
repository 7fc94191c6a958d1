"""Settings of the cold-start planner (:func:`decpomdp.search.plan`), checked when built."""

from __future__ import annotations

from dataclasses import dataclass, field

from infra.checks import as_float, as_int

PHASES = ("ce", "ls")


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of the cold-start planner; defaults are the tuned planner (see the ablation in the README).

    The run cycles through ``phases`` until ``budget`` rollouts are spent or ``patience`` whole cycles
    in a row improved nothing. It starts from a ``start_nodes``-node controller found by a cold
    cross-entropy phase (or, without a ``ce`` phase, node 0 running MA 0).

    Attributes:
        phases: the cycle, a sequence of ``"ce"`` (cross-entropy phase) and ``"ls"`` (local search).
        budget: rollouts the whole run may spend (the run stops at the first step boundary past it).
        patience: whole cycles without an accepted improvement before the run stops.
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
        ce_init_weight: weight of the incumbent in a warm phase's initial distributions, in [0, 1).
        ce_reactive: cross-entropy phases search reactive controllers (tied edges: the next node depends on
            the last observation only, see :mod:`decpomdp.search.cross_entropy`) while the incumbent is
            reactive (the cold phase always); after local search has untied it, phases search whole graphs.
        ls_chain: longest chain insertion (0: single edits only).
        ls_team: also make every move with all agents at once (team moves; no effect with one agent).
        ls_copy: also move by copying one agent's whole graph onto another (no effect with one agent).
        ls_compose: also duel the racing survivors' changes merged into one move.
        ls_candidates: most moves raced per local-search step (chains are sampled beyond it).
        ls_stages: racing stages ``(rollouts, keep)`` of a step; ``keep`` < 1 is a fraction, else a count.
        ls_patience: local-search steps in a row without improvement that end a local-search phase.
        duel_rollouts: fresh rollouts per controller when challengers duel the incumbent.
        duel_z: standard errors of the difference a challenger must win by.
        edge_rate: least traversals per rollout for an edge to be edited.
        visit_rollouts: rollouts counting the incumbent's edge traversals.
    """

    phases: tuple[str, ...] = ("ce", "ls")
    budget: int = 40_000_000
    patience: int = 3
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
    ls_chain: int = 3
    ls_team: bool = True
    ls_compose: bool = True
    ls_copy: bool = True
    ls_candidates: int = 30_000
    ls_stages: tuple[tuple[int, float], ...] = field(default=((16, 0.05), (128, 0.1), (1024, 6)))
    ls_patience: int = 3
    duel_rollouts: int = 4000
    duel_z: float = 2.0
    edge_rate: float = 0.01
    visit_rollouts: int = 500

    def __post_init__(self) -> None:
        phases = _sequence("phases", self.phases)
        if not phases or any(p not in PHASES for p in phases):
            raise ValueError(f"phases: expected a non-empty sequence of {PHASES}, got {self.phases!r}")
        object.__setattr__(self, "phases", phases)
        for name, low in (("budget", 1), ("patience", 1), ("num_nodes", 1), ("start_nodes", 1), ("grow_nodes", 0),
                          ("ce_iterations", 1), ("ce_samples", 1), ("ce_screen_rollouts", 0), ("ce_rollouts", 2),
                          ("ce_elites", 1), ("ce_memory", 0), ("ls_chain", 0), ("ls_candidates", 1),
                          ("ls_patience", 1), ("duel_rollouts", 2), ("visit_rollouts", 1)):
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
        object.__setattr__(self, "ce_init_weight", as_float("ce_init_weight", self.ce_init_weight, 0, 1, high_open=True))
        object.__setattr__(self, "duel_z", as_float("duel_z", self.duel_z, 0))
        object.__setattr__(self, "edge_rate", as_float("edge_rate", self.edge_rate, 0))
        object.__setattr__(self, "ls_stages", _stages(self.ls_stages))
        for name in ("ls_team", "ls_compose", "ls_copy", "ce_reactive"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name}: expected a bool, got {getattr(self, name)!r}")

    @property
    def paper_budget(self) -> int:
        """G-DICE's rollouts at the paper's package-delivery settings: 100 iterations x 100 samples x 80."""
        return 100 * 100 * 80


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
        stages.append((as_int(f"ls_stages[{i}].rollouts", pair[0], 2),
                       as_float(f"ls_stages[{i}].keep", pair[1], 0, low_open=True)))
    if not stages:
        raise ValueError("ls_stages: expected at least one (rollouts, keep) stage")
    return tuple(stages)
