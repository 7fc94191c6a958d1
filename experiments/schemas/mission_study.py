"""Schema of the mission (``experiment=mission`` and ``mission_full``): its perception, planning and closed loop."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from omegaconf import MISSING

from experiments.schemas.blocks import PlanningStudy, imaging_conditions
from experiments.schemas.fields import bounded, choice, count, probability, ranged
from experiments.schemas.noise_studies import ClassifierBlock
from experiments.schemas.planning_studies import DisasterReliefBlock, PlannerBlock
from experiments.schemas.root import Root

PLANNING_MODELS = ("empirical", "generative")
MISSION_VARIANTS = ("hbni", "calibrated", "ssbf", "max_of_mean")


def _check_entries(name: str, entries: list[str]) -> None:
    known = (*MISSION_VARIANTS, *(f"{v}_{m}" for v in MISSION_VARIANTS for m in PLANNING_MODELS))
    unknown = sorted(set(entries) - set(known))
    if unknown:
        raise ValueError(f"{name}: expected policies among {list(known)}, got {unknown}")


@dataclass
class PoweredBlock:
    """``mission.bank.powered``: policies whose value test gets held-out sequences rendered on demand until it
    has its target power, at most ``max_sequences`` per class in all, ``margin`` times what the power calculation
    asks for."""

    entries: list[str] = ranged(_check_entries)
    max_sequences: int = count(2)
    margin: float = bounded(1.0, 4.0)


def _check_directory(name: str, value: str) -> None:
    if not value.strip():
        raise ValueError(f"{name}: expected a directory for cached output banks")


@dataclass
class BankBlock:
    """``mission.bank``: the held-out sequences of the closed loop (per class), their cache and builders."""

    sequences: int = count(2)
    cache_dir: str = ranged(_check_directory)
    workers: int = count(0)
    powered: PoweredBlock = field(default_factory=PoweredBlock)

    @property
    def cache_path(self) -> Path:
        """:attr:`cache_dir` with ``~`` expanded."""
        return Path(os.path.expanduser(self.cache_dir))


@dataclass
class BootstrapBlock:
    """``mission.bootstrap``: stream standard errors by bootstrap over sequence indices."""

    replicates: int = count(2)
    rollouts: int = count(2)


def _check_temper(name: str, t: Any) -> None:
    if t != "fit" and (isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 < t <= 1):
        raise ValueError(f"{name}: expected 'fit' or a float in (0, 1], got {t!r}")


def _calibrations() -> tuple[str, ...]:
    from hbni_pyro import CALIBRATIONS

    return CALIBRATIONS


@dataclass
class MissionBlock:
    """``mission``: the perception side of the mission (data sizes, inference threshold, temper, imaging),
    the planning model and the closed loop."""

    train_per_class: int = count()
    augment: int = count(0)
    calib_sequences: int = count()
    char_sequences: int = count()
    frames: int = count()
    threshold: float = probability()
    temper: Any = ranged(_check_temper)
    hbni_stop: str = choice(("calibrated", "nominal"))
    stop_folds: int = count(2)
    calibration: str = choice(_calibrations)
    conditions: Optional[dict[str, Any]] = imaging_conditions()
    planning_model: str = choice(PLANNING_MODELS)
    compare_planning_models: bool = MISSING
    generative_streams: int = count()
    bank: BankBlock = field(default_factory=BankBlock)
    bootstrap: BootstrapBlock = field(default_factory=BootstrapBlock)

    @property
    def fixed_temper(self) -> float | None:
        """The HBNI temper given in the config (``None``: ``fit`` it on the calibration sequences)."""
        return None if self.temper == "fit" else float(self.temper)

    @property
    def overrides(self) -> dict[str, Any]:
        """The imaging overrides of the ``mission`` preset (none: ``{}``)."""
        return dict(self.conditions) if self.conditions else {}

    @property
    def other_planning_model(self) -> str:
        """The planning model the variants do not plan on (HBNI's comparison entry ``hbni_<other>``)."""
        return PLANNING_MODELS[1 - PLANNING_MODELS.index(self.planning_model)]

    def check(self, path: str) -> None:
        if self.stop_folds > self.calib_sequences:
            raise ValueError(
                f"stop_folds: expected at most calib_sequences={self.calib_sequences}, got {self.stop_folds}"
            )


@dataclass
class Mission(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    planner: Any = field(
        default_factory=PlannerBlock
    )  # plans perfect perception (and every variant without warm starts)
    warm_start: bool = MISSING  # perception variants start from the perfect-perception plan
    warm_planner: Any = field(default_factory=PlannerBlock)  # the planner settings of those warm starts
    domain: Any = field(default_factory=DisasterReliefBlock)
    perception: Any = MISSING
    mission: MissionBlock = field(default_factory=MissionBlock)
    study: PlanningStudy = field(default_factory=PlanningStudy)

    @property
    def variants(self) -> list[str]:
        """The perception variants planned with (``perception``, one name or a list)."""
        return [self.perception] if isinstance(self.perception, str) else list(self.perception)

    def unread(self) -> dict[str, str]:
        out = {"domain.perception": "the mission gives each policy's domain its perception"}
        if not self.warm_start:
            out["warm_planner"] = "warm_start is false: every policy is planned from scratch with planner"
        m = self.mission
        if m.planning_model != "generative" and not (m.compare_planning_models and "hbni" in self.variants):
            out["mission.generative_streams"] = (
                f"no policy plans on the generative model (mission.planning_model={m.planning_model}, "
                f"mission.compare_planning_models={m.compare_planning_models}, perception={self.variants})"
            )
        return out

    def check(self, path: str) -> None:
        chosen = self.variants
        unknown = [v for v in chosen if v not in MISSION_VARIANTS]
        if unknown or not chosen:
            raise ValueError(f"perception: expected a subset of {list(MISSION_VARIANTS)}, got {chosen}")
        from hbni_pyro import noise_model

        if self.mission.temper != "fit" and noise_model(self.hbni.model).correlated_frames:
            raise ValueError(
                f"mission.temper: the {self.hbni.model!r} model counts correlated frames itself (its fitted "
                f"frame correlation); a fixed temper is for hbni.model=paper or confusion, got {self.mission.temper!r}"
            )
