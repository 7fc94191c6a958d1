"""Schema of the new-place study (``experiment=new_place``): the old place the classifier and its calibration come
from, the new place the mission runs in, what the robot has there (``K`` labelled sequences per class, ``U``
unlabelled streams in a class mix), the adaptation's prior, planning, the closed loop and the photographs."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from omegaconf import MISSING

from experiments.schemas.blocks import PlanningStudy, imaging_conditions
from experiments.schemas.fields import bounded, choice, count, probability, ranged
from experiments.schemas.mission_study import BootstrapBlock
from experiments.schemas.noise_studies import ClassifierBlock
from experiments.schemas.planning_studies import DisasterReliefBlock, PlannerBlock
from experiments.schemas.root import Root
from hbni_infra.checks import as_int


def _calibrations() -> tuple[str, ...]:
    from hbni_pyro import CALIBRATIONS

    return CALIBRATIONS


def _classes() -> list[str]:
    from decpomdp.domains.disaster_relief import CLASSES

    return list(CLASSES)


def _check_labelled(name: str, values: list[int]) -> None:
    if not values or any(isinstance(k, bool) or not isinstance(k, int) or k < 0 for k in values):
        raise ValueError(f"{name}: expected labelled sequences per class, ints >= 0, got {list(values)}")
    if list(values) != sorted(set(values)):
        raise ValueError(f"{name}: expected distinct labelled sequences per class in rising order, got {list(values)}")


def _check_mix(name: str, weights: list[float]) -> None:
    M = len(_classes())
    if len(weights) != M or any(not (math.isfinite(w) and w > 0) for w in weights):
        raise ValueError(f"{name}: expected {M} positive weights, one per class, got {list(weights)}")


def _check_unlabelled(name: str, value: int) -> None:
    as_int(name, value, len(_classes()))  # at least one stream per class


def _check_directory(name: str, value: str) -> None:
    if not value.strip():
        raise ValueError(f"{name}: expected a directory for cached classifier outputs and banks")


def _check_camera(name: str, overrides: dict[str, Any]) -> None:
    try:
        _camera(overrides)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: {exc}") from None


def _camera(overrides: dict[str, Any]) -> Any:
    """The ``"degraded"`` photo preset with ``overrides`` (lists as the tuples its ranges are)."""
    from classifiers.photos import get_photo_conditions

    values = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    return dataclasses.replace(get_photo_conditions("degraded"), **values)


@dataclass
class PlaceBlock:
    """An imaging place: overrides of the mission preset's conditions (:func:`classifiers.data.get_conditions`)."""

    conditions: dict[str, Any] = imaging_conditions()

    @property
    def imaging(self) -> Any:
        """The place's :class:`classifiers.data.Conditions`."""
        from classifiers.data import get_conditions

        return get_conditions("mission", **self.conditions)


@dataclass
class OldPlaceBlock(PlaceBlock):
    """``new_place.old``: the place the classifier's calibration comes from (the mission's), its labelled sequences
    per class and the folds HBNI's stop is chosen on there."""

    sequences: int = count(2)
    stop_folds: int = count(2)

    def check(self, path: str) -> None:
        if self.stop_folds > self.sequences:
            raise ValueError(f"stop_folds: expected at most sequences={self.sequences}, got {self.stop_folds}")


@dataclass
class HeldOutBankBlock:
    """``new_place.bank``: held-out new-place sequences per class of the closed loop and the processes that build
    them."""

    sequences: int = count(2)
    workers: int = count(0)


@dataclass
class NewPlacePhotosBlock:
    """``new_place.photos``: the same comparison on real photographs; the new camera's degradation overrides the
    ``"degraded"`` preset's fields (:class:`classifiers.photos.PhotoConditions`), which is the old camera."""

    train_per_class: int = count(2)
    augment: int = count(0)
    old_sequences: int = count(2)
    test_sequences: int = count(2)
    conditions: dict[str, Any] = ranged(_check_camera)

    @property
    def camera(self) -> Any:
        """The new camera's :class:`classifiers.photos.PhotoConditions`."""
        return _camera(self.conditions)


@dataclass
class NewPlaceBlock:
    """``new_place``: the classifier's training, the old and the new place, what the robot has there (``labelled``
    sequences per class, ``unlabelled`` streams in the class ``mix``), the adaptation's prior, the process, the
    planning tables, the closed loop and the photographs (``None``: skipped)."""

    train_per_class: int = count()
    augment: int = count(0)
    frames: int = count()
    threshold: float = probability()
    calibration: str = choice(_calibrations)
    old: OldPlaceBlock = field(default_factory=OldPlaceBlock)
    new: PlaceBlock = field(default_factory=PlaceBlock)
    labelled: list[int] = ranged(_check_labelled)
    unlabelled: int = ranged(_check_unlabelled)
    mix: list[float] = ranged(_check_mix)
    shift_sd: float = bounded(1e-3, 10.0)
    prevalence: float = bounded(1e-3, 1e3)
    generative_streams: int = count()
    cache_dir: str = ranged(_check_directory)
    bank: HeldOutBankBlock = field(default_factory=HeldOutBankBlock)
    bootstrap: BootstrapBlock = field(default_factory=BootstrapBlock)
    photos: Optional[NewPlacePhotosBlock] = MISSING

    @property
    def cache_path(self) -> Path:
        """:attr:`cache_dir` with ``~`` expanded."""
        return Path(os.path.expanduser(self.cache_dir))

    def unlabelled_counts(self) -> list[int]:
        """Streams per class of the :attr:`unlabelled` ones in the class :attr:`mix` (largest remainders; every class
        at least one)."""
        raw = [w / sum(self.mix) * self.unlabelled for w in self.mix]
        counts = [max(1, math.floor(r)) for r in raw]
        for i in sorted(range(len(raw)), key=lambda i: raw[i] - math.floor(raw[i]), reverse=True):
            if sum(counts) >= self.unlabelled:
                break
            counts[i] += 1
        return counts


@dataclass
class NewPlace(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    planner: Any = field(default_factory=PlannerBlock)  # plans perfect perception from scratch
    warm_planner: Any = field(default_factory=PlannerBlock)  # refines that plan on each variant's table
    domain: Any = field(default_factory=DisasterReliefBlock)
    new_place: NewPlaceBlock = field(default_factory=NewPlaceBlock)
    study: PlanningStudy = field(default_factory=PlanningStudy)

    def unread(self) -> dict[str, str]:
        return {
            "domain.perception": "the study gives each policy's domain its perception",
            "hbni.model": "the study fits the sequence model, the one hbni_pyro.adapt adapts",
        }

    def noise_models(self) -> tuple[str, ...]:
        return ("sequence",)
