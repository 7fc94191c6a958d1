"""The planner's settings the decpomdp tests share: small runs, each named for what it is for, every test giving
only the settings it is about."""

from __future__ import annotations

import dataclasses

from decpomdp.search import PlannerConfig

EXACT_SCORES = {"budget": 10**9, "ce_screen_rollouts": 0, "ce_rollouts": 2, "duel_rollouts": 2, "edge_rate": 0.0}
"""Under an exact scorer (:class:`decpomdp.search.ExactScorer`) a score needs no rollouts: no screening, the fewest
rollouts per score and duel, no edge statistics, and a budget that never binds."""


def exact(**settings) -> PlannerConfig:
    """A planner for an exact scorer (:data:`EXACT_SCORES`), its search sized by ``settings``."""
    return PlannerConfig(**EXACT_SCORES, **settings)


TINY = PlannerConfig(
    budget=6_000,
    patience=1,
    num_nodes=4,
    start_nodes=2,
    grow_nodes=1,
    ce_iterations=2,
    ce_samples=12,
    ce_screen_rollouts=4,
    ce_screen_keep=0.5,
    ce_rollouts=8,
    ce_elites=3,
    ce_memory=2,
    ls_chain=1,
    ls_candidates=40,
    ls_stages=((4, 0.5), (8, 2)),
    ls_patience=1,
    duel_rollouts=50,
    visit_rollouts=20,
)
"""Every phase of the cold-start planner in a few thousand rollouts of a hand-written toy domain."""

SHORT = PlannerConfig(
    budget=150_000,
    num_nodes=6,
    ce_iterations=3,
    ce_samples=60,
    ls_candidates=300,
    ls_stages=((8, 0.1), (64, 4)),
    duel_rollouts=300,
    visit_rollouts=100,
    patience=1,
)
"""A short cold-start run on disaster relief: a controller that has learnt something, in seconds."""


def tiny(**changes) -> PlannerConfig:
    """:data:`TINY` with ``changes``."""
    return dataclasses.replace(TINY, **changes)


def short(**changes) -> PlannerConfig:
    """:data:`SHORT` with ``changes``."""
    return dataclasses.replace(SHORT, **changes)
