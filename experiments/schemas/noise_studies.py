"""Schemas of the perception experiments: the paper's toy studies, perception replay, the noise-model comparison
and the live stream."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING

from experiments.schemas.blocks import HyperPriorBlock, check_conditions, imaging_conditions, noise_levels
from experiments.schemas.fields import count, optional_probability, probabilities, probability, ranged
from experiments.schemas.root import PaperStudy, Root
from experiments.schemas.targets import target_schema
from hbni_infra.checks import as_probability

ClassifierBlock = target_schema("classifiers.FrameClassifier")


@dataclass
class ToyBlock:
    theta: list[float] = noise_levels()
    per_class: int = count()
    near_perfect_hyperprior: Any = field(default_factory=HyperPriorBlock)


@dataclass
class HBNIToy(Root):
    toy: ToyBlock = field(default_factory=ToyBlock)

    def unread(self) -> dict[str, str]:
        return {"hbni.model": "the toy fits the paper's model", "hbni.filter": "the toy filters no stream"}

    def noise_models(self) -> tuple[str, ...]:
        return ("paper",)


def _check_sizes(name: str, sizes: list[int]) -> None:
    if not sizes or min(sizes) < 1:
        raise ValueError(f"{name}: expected sizes >= 1, got {list(sizes)}")


@dataclass
class FilteringStudy:
    true_theta: list[float] = noise_levels()
    training_sizes: list[int] = ranged(_check_sizes)
    num_training_sets: int = count()
    num_trials: int = count()
    max_len: int = count()
    filter_draws: int = count()
    targets: list[float] = probabilities()


@dataclass
class FilteringError(PaperStudy):
    study: FilteringStudy = field(default_factory=FilteringStudy)


@dataclass
class MacroStudy:
    true_theta: list[float] = noise_levels()
    training_per_class: int = count()
    threshold: float = probability()
    max_frames: int = count()
    num_streams: int = count()
    filter_draws: int = count()


@dataclass
class MacroObservation(PaperStudy):
    study: MacroStudy = field(default_factory=MacroStudy)


def _check_objects(name: str, classes: list[str]) -> None:
    from classifiers.data import OBJECTS

    unknown = [c for c in classes if c not in OBJECTS]
    if len(classes) < 2 or unknown or len(set(classes)) != len(classes):
        raise ValueError(f"{name}: expected at least 2 distinct objects of {list(OBJECTS)}, got {list(classes)}")


@dataclass
class ReplayStudy:
    classes: list[str] = ranged(_check_objects)
    train_per_class: int = count()
    augment: int = count(0)
    calib_sequences: int = count()
    test_sequences: int = count()
    frames: int = count()
    threshold: float = probability()
    mission: dict[str, Any] = imaging_conditions()


@dataclass
class PerceptionReplay(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    study: ReplayStudy = field(default_factory=ReplayStudy)


ANNOTATIONS = ("video", "strip", "bag")


@dataclass
class StreamBlock:
    """``stream``: where frames come from, the saved models, the macro-observation process, the pictures."""

    source: Any = MISSING  # a ROS bag, a video file, a folder of frames or a camera index
    topic: Optional[str] = MISSING  # a bag's image topic (None: its only one)
    window: Optional[list[Optional[float]]] = MISSING  # [start, stop] seconds from a bag's start
    max_input_frames: Optional[int] = count(optional=True)
    run: Optional[str] = MISSING  # a mission run directory; latest: the newest completed one under outputs/mission
    classifier: Optional[str] = MISSING
    posterior: Optional[str] = MISSING
    classes: Optional[list[str]] = MISSING
    temper: Optional[float] = optional_probability()
    threshold: float = probability()
    max_frames: int = count()
    batch: int = count()
    annotate: list[str] = MISSING
    bag: Optional[bool] = MISSING  # write the ROS output bag (None: when the source is a bag)
    controller: Optional[str] = MISSING  # a saved JointController
    agent: int = count(0)
    observations: Any = MISSING  # class name -> controller observation name (null: the class names)

    @property
    def is_bag(self) -> bool:
        """Whether the source is a ROS bag."""
        from classifiers.bags import is_bag

        return isinstance(self.source, str) and is_bag(self.source)

    def check(self, path: str) -> None:
        from pathlib import Path

        source = self.source
        if (
            isinstance(source, bool)
            or not isinstance(source, (str, int))
            or (isinstance(source, str) and not source.strip())
        ):
            raise ValueError(
                f"source: expected a video file, a folder of frames or a camera index, or a ROS bag, got {source!r}"
            )
        if isinstance(source, str) and not source.isdigit() and not Path(source).exists():
            raise ValueError(f"source: no such video file or folder {source!r}, nor a ROS bag")
        bag = self.is_bag
        for name in ("topic", "window"):
            if getattr(self, name) is not None and not bag:
                raise ValueError(f"{name}: only a ROS bag source has topics and receive times, got source {source!r}")
        if self.topic is not None and not self.topic.strip():
            raise ValueError(f"topic: expected a topic name or null, got {self.topic!r}")
        window = None if self.window is None else list(self.window)
        if window is not None:
            if not (
                len(window) == 2
                and window[0] is not None
                and 0 <= window[0] < (math.inf if window[1] is None else window[1])
            ):
                raise ValueError(
                    f"window: expected [start, stop] seconds from the bag's start, 0 <= start < stop (stop null: "
                    f"to the end), got {list(self.window)}"
                )
        for name in ("run", "classifier", "posterior", "controller"):
            value = getattr(self, name)
            if value is not None and not (name == "run" and value == "latest") and not Path(value).exists():
                raise ValueError(f"{name}: no such file or directory {value!r}")
        if self.run is None and (self.classifier is None or self.posterior is None):
            raise ValueError(
                "run: expected a finished mission run (or latest), or both stream.classifier and stream.posterior"
            )
        unknown = [a for a in self.annotate if a not in ANNOTATIONS]
        if unknown:
            raise ValueError(f"annotate: expected a subset of {list(ANNOTATIONS)}, got {list(self.annotate)}")
        if "bag" in self.annotate and not (bag if self.bag is None else self.bag):
            raise ValueError(
                "annotate: 'bag' puts the annotated frames into the output bag, which stream.bag does not write "
                "(null: only for a bag source)"
            )
        if self.observations is not None and not (
            isinstance(self.observations, dict)
            and all(isinstance(k, str) and isinstance(v, str) for k, v in self.observations.items())
        ):
            raise ValueError(
                f"observations: expected a mapping of class names to observation names, got {self.observations!r}"
            )
        if self.observations and self.controller is None:
            raise ValueError("observations: maps classes to a controller's observations; give stream.controller")


@dataclass
class Stream(Root):
    stream: StreamBlock = field(default_factory=StreamBlock)

    def unread(self) -> dict[str, str]:
        loaded = "the stream loads a fitted posterior"
        out = {"seed": "the stream draws no random numbers", "hbni.model": loaded, "hbni.fit": loaded}
        out["hbni.hyperprior"] = loaded
        if self.stream.classifier is not None and self.stream.posterior is not None:
            out["stream.run"] = "stream.classifier and stream.posterior are both given"
        if self.stream.controller is None:
            out["stream.agent"] = "stream.controller is null: no robot's controller runs"
        return out

    def noise_models(self) -> tuple[str, ...]:
        return ()


@dataclass
class NoiseToyBlock:
    theta: list[float] = noise_levels()
    training_size: int = count()
    num_training_sets: int = count()
    num_trials: int = count()
    max_len: int = count()
    filter_draws: int = count()
    target: float = probability()

    def check(self, path: str) -> None:
        if self.training_size % len(self.theta):
            raise ValueError(
                f"training_size: expected a multiple of the {len(self.theta)} classes, got {self.training_size}"
            )
        if self.num_trials % self.num_training_sets:
            raise ValueError(
                f"num_trials: expected a multiple of num_training_sets ({self.num_training_sets}), got {self.num_trials}"
            )


@dataclass
class NoiseMissionBlock:
    """``study.mission`` and ``study.photos``: the sizes of a condition (snapshots, sequences, frames)."""

    train_per_class: int = count()
    augment: int = count(0)
    calib_sequences: int = count()
    test_sequences: int = count()
    frames: int = count()


def _check_thresholds(name: str, values: list[float]) -> None:
    if not values:
        raise ValueError(f"{name}: expected at least one threshold")
    for t in values:
        as_probability(name, t, allow_zero=False)


def _check_share(name: str, value: float) -> None:
    if not 0 < value < 1:
        raise ValueError(f"{name}: expected a share in (0, 1), got {value}")


@dataclass
class NoiseStudy:
    """``study`` of the noise-model comparison."""

    models: list[str] = MISSING
    thresholds: list[float] = ranged(_check_thresholds)
    curve_thresholds: list[float] = ranged(_check_thresholds)
    cache_dir: Optional[str] = MISSING
    toy: NoiseToyBlock = field(default_factory=NoiseToyBlock)
    mission: NoiseMissionBlock = field(default_factory=NoiseMissionBlock)
    conditions: dict[str, Any] = MISSING
    images: Optional[str] = MISSING
    images_calibration: float = ranged(_check_share)
    photos: Optional[NoiseMissionBlock] = MISSING

    def check(self, path: str) -> None:
        from hbni_pyro import model_names

        if (
            not self.models
            or any(m not in model_names() for m in self.models)
            or len(set(self.models)) != len(self.models)
        ):
            raise ValueError(f"models: expected distinct models of {list(model_names())}, got {list(self.models)}")
        for name, overrides in self.conditions.items():
            check_conditions(f"conditions.{name}", overrides)
        if not self.conditions and self.images is None and self.photos is None:
            raise ValueError("conditions: expected at least one imaging condition (or study.images, study.photos)")


@dataclass
class NoiseModels(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    study: NoiseStudy = field(default_factory=NoiseStudy)

    def unread(self) -> dict[str, str]:
        out = {"hbni.model": "study.models names the models compared"}
        if self.study.images is None:
            out["study.images_calibration"] = "study.images is null: no image folder to split"
        return out

    def noise_models(self) -> tuple[str, ...]:
        return tuple(self.study.models)
