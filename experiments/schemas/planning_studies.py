"""Schemas of the planning experiments: package delivery, disaster relief and the ``.dpomdp`` benchmarks."""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING

from experiments.schemas.blocks import BaselineStudy, check_seeded
from experiments.schemas.fields import choice, count, probabilities, probability
from experiments.schemas.root import NoPerception
from experiments.schemas.targets import target_schema

PlannerBlock = target_schema("decpomdp.search.PlannerConfig")
DisasterReliefBlock = target_schema("decpomdp.domains.DisasterRelief", runtime=("perception",))
PackageDeliveryBlock = target_schema("decpomdp.domains.PackageDelivery")


@dataclass
class PackageStudy(BaselineStudy):
    alpha_sweep: list[float] = probabilities()
    sweep_iterations: int = count()


@dataclass
class ComparedPlanners:
    """``planners``: the presets a planning experiment compares (both ``conf/planner`` options, one schema)."""

    cold: Any = field(default_factory=PlannerBlock)
    gdice: Any = field(default_factory=PlannerBlock)


@dataclass
class PlanningExperiment(NoPerception):
    """A planning experiment: the cold-start planner, G-DICE cold and seeded from the greedy controller, baselines."""

    planners: ComparedPlanners = field(default_factory=ComparedPlanners)
    study: BaselineStudy = field(default_factory=BaselineStudy)

    def check(self, path: str) -> None:
        check_seeded(self.planners.gdice, self.study.seeded)


@dataclass
class PaperComparison:
    """``reference``: the paper's G-DICE on the reference-rules preset of package delivery (and on this domain)."""

    domain: Any = field(default_factory=PackageDeliveryBlock)
    planner: Any = field(default_factory=PlannerBlock)
    runs: int = count()


@dataclass
class PackageDeliveryExperiment(PlanningExperiment):
    domain: Any = field(default_factory=PackageDeliveryBlock)
    study: PackageStudy = field(default_factory=PackageStudy)
    reference: PaperComparison = field(default_factory=PaperComparison)


@dataclass
class DisasterReliefExperiment(PlanningExperiment):
    domain: Any = field(default_factory=DisasterReliefBlock)


@dataclass
class Caps:
    iterations: Optional[int] = count(optional=True)
    samples: Optional[int] = count(optional=True)
    restarts: Optional[int] = count(optional=True)


def _problem_names() -> tuple[str, ...]:
    from decpomdp.dpomdp import problem_names

    return tuple(problem_names())


@dataclass
class BenchmarkRow:
    """One row of ``dpomdp_benchmarks``: a shipped problem, its horizon (None: infinite) and optimum."""

    problem: str = choice(_problem_names)
    gamma: float = probability()
    horizon: Optional[int] = count(optional=True)
    optimum: Optional[float] = MISSING
    source: str = MISSING
    evaluator: str = choice(("exact", "monte_carlo"), "exact")  # a row's own defaults: a dict of rows has none
    rollouts: int = count(2, default=200)
    restarts: int = count()
    gdice: dict[str, Any] = MISSING

    def check(self, path: str) -> None:
        if self.horizon is None and self.gamma >= 1:
            raise ValueError("horizon: null (infinite) needs gamma < 1")
        if self.evaluator == "monte_carlo" and self.horizon is None:
            raise ValueError("evaluator: monte_carlo rollouts need a finite horizon")
        if self.optimum is not None and not self.source:
            raise ValueError("source: a published optimum needs its source")


@dataclass
class PaperBudget:
    """The planner settings of each row's run at the paper's budget (N_s samples, N_k iterations)."""

    ce_samples: int = count()
    ce_iterations: int = count()


@dataclass
class BenchmarkStudy:
    threads: int = count()
    random_controllers: int = count(2)
    paper_budget: PaperBudget = field(default_factory=PaperBudget)
    caps: Caps = field(default_factory=Caps)
    solve: dict[str, Any] = MISSING  # keyword arguments of decpomdp.solve, the same for every row
    only: Optional[list[str]] = MISSING  # run these rows alone (None: every row)
    rows: dict[str, BenchmarkRow] = MISSING

    def check(self, path: str) -> None:
        from decpomdp import solve
        from decpomdp.search import PlannerConfig

        known = {n for n, p in inspect.signature(solve).parameters.items() if p.kind is p.KEYWORD_ONLY}
        known |= {f.name for f in dataclasses.fields(PlannerConfig)}
        unknown = sorted(set(self.solve) - known - {"seed", "threads"})
        if unknown:
            raise ValueError(
                f"solve: unknown settings {unknown}; expected keywords of decpomdp.solve or "
                "PlannerConfig fields (seed and threads come from the study)"
            )
        missing = sorted(set(self.only or ()) - set(self.rows))
        if missing:
            raise ValueError(f"only: unknown rows {missing}")
        if not self.rows:
            raise ValueError("rows: expected at least one row")


@dataclass
class DPOMDPBenchmarks(NoPerception):
    planner: Any = field(default_factory=PlannerBlock)
    study: BenchmarkStudy = field(default_factory=BenchmarkStudy)
