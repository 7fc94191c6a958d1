"""One schema per experiment: the root of its composed config (``conf/experiment/<name>.yaml``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING, DictConfig

from experiments.schemas.blocks import (
    BaselineStudy,
    HBNIBlock,
    HyperPriorBlock,
    PlanningStudy,
    check_seeded,
)
from experiments.schemas.targets import target_schema
from hbni_infra.checks import as_choice, as_float, as_int, as_probability

ClassifierBlock = target_schema("classifiers.FrameClassifier")
PlannerBlock = target_schema("decpomdp.search.PlannerConfig")
DisasterReliefBlock = target_schema("decpomdp.domains.DisasterRelief", runtime=("perception",))
PackageDeliveryBlock = target_schema("decpomdp.domains.PackageDelivery")


@dataclass
class Paths:
    """``paths``: where runs, sweeps and caches go (``conf/config.yaml``)."""

    root: str = MISSING  # the values are conf/config.yaml's
    outputs: str = MISSING
    multirun: str = MISSING
    cache: str = MISSING


@dataclass
class Root:
    """Keys every experiment has."""

    paths: Paths = field(default_factory=Paths)
    name: str = MISSING
    entry: str = MISSING
    headline: list[str] = MISSING  # metrics a sweep report shows (paths into metrics.json)
    seed: int = MISSING
    progress: bool = MISSING
    hbni: HBNIBlock = field(default_factory=HBNIBlock)

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        """Key -> why the experiment never reads it, for the composed config ``cfg`` (refused when set:
        :func:`experiments.schemas.check_overrides`). The settings a planner ignores are added there."""
        return {}

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        """The noise models the experiment fits (their hyperprior fields are the ones it reads)."""
        return (cfg.hbni.model,)


NO_NOISE_MODEL = "it fits no noise model"


@dataclass
class NoPerception(Root):
    """A study that plans on a domain and fits no noise model: the ``hbni`` block is not read."""

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        return {"hbni": NO_NOISE_MODEL}

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return ()


def _check_theta(name: str, theta: list[float]) -> None:
    if len(theta) < 2 or any(not (math.isfinite(t) and t > 0) for t in theta):
        raise ValueError(f"{name}: expected at least 2 noise levels > 0, all finite, got {list(theta)}")


def _check_conditions(name: str, overrides: dict[str, Any] | None) -> None:
    from classifiers.data import get_conditions

    try:
        get_conditions("mission", **(overrides or {}))
    except (TypeError, ValueError) as exc:
        message = str(exc).removeprefix("conditions: ")
        raise ValueError(f"{name}: {message}") from None


@dataclass
class ToyBlock:
    theta: list[float] = MISSING
    per_class: int = MISSING
    near_perfect_hyperprior: Any = field(default_factory=HyperPriorBlock)

    def check(self, path: str) -> None:
        _check_theta("theta", self.theta)
        as_int("per_class", self.per_class, 1)


@dataclass
class HBNIToy(Root):
    toy: ToyBlock = field(default_factory=ToyBlock)

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        return {"hbni.model": "the toy fits the paper's model", "hbni.filter": "the toy filters no stream"}

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return ("paper",)


@dataclass
class FilteringStudy:
    true_theta: list[float] = MISSING
    training_sizes: list[int] = MISSING
    num_training_sets: int = MISSING
    num_trials: int = MISSING
    max_len: int = MISSING
    filter_draws: int = MISSING
    targets: list[float] = MISSING

    def check(self, path: str) -> None:
        _check_theta("true_theta", self.true_theta)
        if not self.training_sizes or min(self.training_sizes) < 1:
            raise ValueError(f"training_sizes: expected sizes >= 1, got {list(self.training_sizes)}")
        for name in ("num_training_sets", "num_trials", "max_len", "filter_draws"):
            as_int(name, getattr(self, name), 1)
        for t in self.targets:
            as_probability("targets", t, allow_zero=False)


@dataclass
class PaperStudy(Root):
    """A study of the paper's own noise model: ``hbni.model`` is not read."""

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        return {"hbni.model": "the study fits the paper's model"}

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return ("paper",)


@dataclass
class FilteringError(PaperStudy):
    study: FilteringStudy = field(default_factory=FilteringStudy)


@dataclass
class MacroStudy:
    true_theta: list[float] = MISSING
    training_per_class: int = MISSING
    threshold: float = MISSING
    max_frames: int = MISSING
    num_streams: int = MISSING
    filter_draws: int = MISSING

    def check(self, path: str) -> None:
        _check_theta("true_theta", self.true_theta)
        as_probability("threshold", self.threshold, allow_zero=False)
        for name in ("training_per_class", "max_frames", "num_streams", "filter_draws"):
            as_int(name, getattr(self, name), 1)


@dataclass
class MacroObservation(PaperStudy):
    study: MacroStudy = field(default_factory=MacroStudy)


@dataclass
class ReplayStudy:
    classes: list[str] = MISSING
    train_per_class: int = MISSING
    augment: int = MISSING
    calib_sequences: int = MISSING
    test_sequences: int = MISSING
    frames: int = MISSING
    threshold: float = MISSING
    mission: dict[str, Any] = MISSING

    def check(self, path: str) -> None:
        from classifiers.data import OBJECTS

        unknown = [c for c in self.classes if c not in OBJECTS]
        if len(self.classes) < 2 or unknown or len(set(self.classes)) != len(self.classes):
            raise ValueError(
                f"classes: expected at least 2 distinct objects of {list(OBJECTS)}, got {list(self.classes)}"
            )
        for name in ("train_per_class", "calib_sequences", "test_sequences", "frames"):
            as_int(name, getattr(self, name), 1)
        as_int("augment", self.augment, 0)
        as_probability("threshold", self.threshold, allow_zero=False)
        _check_conditions("mission", self.mission)


@dataclass
class PerceptionReplay(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    study: ReplayStudy = field(default_factory=ReplayStudy)


@dataclass
class PackageStudy(BaselineStudy):
    alpha_sweep: list[float] = MISSING
    sweep_iterations: int = MISSING

    def check(self, path: str) -> None:
        super().check(path)
        as_int("sweep_iterations", self.sweep_iterations, 1)
        for alpha in self.alpha_sweep:
            as_probability("alpha_sweep", alpha, allow_zero=False)


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
    runs: int = MISSING

    def check(self, path: str) -> None:
        as_int("runs", self.runs, 1)


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
    iterations: Optional[int] = MISSING
    samples: Optional[int] = MISSING
    restarts: Optional[int] = MISSING

    def check(self, path: str) -> None:
        for name in ("iterations", "samples", "restarts"):
            if getattr(self, name) is not None:
                as_int(name, getattr(self, name), 1)


@dataclass
class BenchmarkRow:
    """One row of ``dpomdp_benchmarks``: a shipped problem, its horizon (None: infinite) and optimum."""

    problem: str = MISSING
    gamma: float = MISSING
    horizon: Optional[int] = MISSING
    optimum: Optional[float] = MISSING
    source: str = MISSING
    evaluator: str = "exact"  # a row's own defaults: a dict of rows has no YAML default per row
    rollouts: int = 200
    restarts: int = MISSING
    gdice: dict[str, Any] = MISSING

    def check(self, path: str) -> None:
        from decpomdp.dpomdp import problem_names

        as_choice("problem", self.problem, tuple(problem_names()))
        as_probability("gamma", self.gamma, allow_zero=False)
        if self.horizon is None and self.gamma >= 1:
            raise ValueError("horizon: null (infinite) needs gamma < 1")
        if self.horizon is not None:
            as_int("horizon", self.horizon, 1)
        as_choice("evaluator", self.evaluator, ("exact", "monte_carlo"))
        if self.evaluator == "monte_carlo" and self.horizon is None:
            raise ValueError("evaluator: monte_carlo rollouts need a finite horizon")
        as_int("rollouts", self.rollouts, 2)
        as_int("restarts", self.restarts, 1)
        if self.optimum is not None and not self.source:
            raise ValueError("source: a published optimum needs its source")


@dataclass
class PaperBudget:
    """The planner settings of each row's run at the paper's budget (N_s samples, N_k iterations)."""

    ce_samples: int = MISSING
    ce_iterations: int = MISSING

    def check(self, path: str) -> None:
        as_int("ce_samples", self.ce_samples, 1)
        as_int("ce_iterations", self.ce_iterations, 1)


@dataclass
class BenchmarkStudy:
    threads: int = MISSING
    random_controllers: int = MISSING
    paper_budget: PaperBudget = field(default_factory=PaperBudget)
    caps: Caps = field(default_factory=Caps)
    solve: dict[str, Any] = MISSING  # keyword arguments of decpomdp.solve, the same for every row
    only: Optional[list[str]] = MISSING  # run these rows alone (None: every row)
    rows: dict[str, BenchmarkRow] = MISSING

    def check(self, path: str) -> None:
        import dataclasses
        import inspect

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
        as_int("threads", self.threads, 1)
        missing = sorted(set(self.only or ()) - set(self.rows))
        if missing:
            raise ValueError(f"only: unknown rows {missing}")
        as_int("random_controllers", self.random_controllers, 2)
        if not self.rows:
            raise ValueError("rows: expected at least one row")
        for name, row in self.rows.items():
            try:
                row.check(f"{path}.rows.{name}")
            except ValueError as exc:
                raise ValueError(f"{path}.rows.{name}.{exc}") from None


@dataclass
class DPOMDPBenchmarks(NoPerception):
    planner: Any = field(default_factory=PlannerBlock)
    study: BenchmarkStudy = field(default_factory=BenchmarkStudy)


PLANNING_MODELS = ("empirical", "generative")
MISSION_VARIANTS = ("hbni", "calibrated", "ssbf", "max_of_mean")


@dataclass
class PoweredBlock:
    """``mission.bank.powered``: policies whose value test gets held-out sequences rendered on demand until it
    has its target power, at most ``max_sequences`` per class in all, ``margin`` times what the power calculation
    asks for."""

    entries: list[str] = MISSING
    max_sequences: int = MISSING
    margin: float = MISSING

    def check(self, path: str) -> None:
        known = (*MISSION_VARIANTS, *(f"{v}_{m}" for v in MISSION_VARIANTS for m in PLANNING_MODELS))
        unknown = sorted(set(self.entries) - set(known))
        if unknown:
            raise ValueError(f"entries: expected policies among {list(known)}, got {unknown}")
        as_int("max_sequences", self.max_sequences, 2)
        as_float("margin", self.margin, 1.0, 4.0)


@dataclass
class BankBlock:
    """``mission.bank``: the held-out sequences of the closed loop (per class), their cache and builders."""

    sequences: int = MISSING
    cache_dir: str = MISSING
    workers: int = MISSING
    powered: PoweredBlock = field(default_factory=PoweredBlock)

    def check(self, path: str) -> None:
        as_int("sequences", self.sequences, 2)
        as_int("workers", self.workers, 0)
        if not self.cache_dir.strip():
            raise ValueError("cache_dir: expected a directory for cached output banks")


@dataclass
class BootstrapBlock:
    """``mission.bootstrap``: stream standard errors by bootstrap over sequence indices."""

    replicates: int = MISSING
    rollouts: int = MISSING

    def check(self, path: str) -> None:
        as_int("replicates", self.replicates, 2)
        as_int("rollouts", self.rollouts, 2)


@dataclass
class MissionBlock:
    """``mission``: the perception side of the mission (data sizes, inference threshold, temper, imaging),
    the planning model and the closed loop."""

    train_per_class: int = MISSING
    augment: int = MISSING
    calib_sequences: int = MISSING
    char_sequences: int = MISSING
    frames: int = MISSING
    threshold: float = MISSING
    temper: Any = MISSING
    hbni_stop: str = MISSING
    stop_folds: int = MISSING
    calibration: str = MISSING
    conditions: Optional[dict[str, Any]] = MISSING
    planning_model: str = MISSING
    compare_planning_models: bool = MISSING
    generative_streams: int = MISSING
    bank: BankBlock = field(default_factory=BankBlock)
    bootstrap: BootstrapBlock = field(default_factory=BootstrapBlock)

    def check(self, path: str) -> None:
        for name in ("train_per_class", "calib_sequences", "char_sequences", "frames", "generative_streams"):
            as_int(name, getattr(self, name), 1)
        as_choice("planning_model", self.planning_model, PLANNING_MODELS)
        from hbni_pyro.frame_calibration import CALIBRATIONS

        as_choice("calibration", self.calibration, CALIBRATIONS)
        as_choice("hbni_stop", self.hbni_stop, ("calibrated", "nominal"))
        if as_int("stop_folds", self.stop_folds, 2) > self.calib_sequences:
            raise ValueError(
                f"stop_folds: expected at most calib_sequences={self.calib_sequences}, got {self.stop_folds}"
            )
        as_int("augment", self.augment, 0)
        as_probability("threshold", self.threshold, allow_zero=False)
        t = self.temper
        if t != "fit" and (isinstance(t, bool) or not isinstance(t, (int, float)) or not 0 < t <= 1):
            raise ValueError(f"temper: expected 'fit' or a float in (0, 1], got {t!r}")
        _check_conditions("conditions", self.conditions)


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

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        out = {"domain.perception": "the mission gives each policy's domain its perception"}
        if not cfg.warm_start:
            out["warm_planner"] = "warm_start is false: every policy is planned from scratch with planner"
        chosen = [cfg.perception] if isinstance(cfg.perception, str) else list(cfg.perception)
        m = cfg.mission
        if m.planning_model != "generative" and not (m.compare_planning_models and "hbni" in chosen):
            out["mission.generative_streams"] = (
                f"no policy plans on the generative model (mission.planning_model={m.planning_model}, "
                f"mission.compare_planning_models={m.compare_planning_models}, perception={chosen})"
            )
        return out

    def check(self, path: str) -> None:
        chosen = [self.perception] if isinstance(self.perception, str) else list(self.perception)
        unknown = [v for v in chosen if v not in MISSION_VARIANTS]
        if unknown or not chosen:
            raise ValueError(f"perception: expected a subset of {list(MISSION_VARIANTS)}, got {chosen}")
        from hbni_pyro.variants import noise_model

        if self.mission.temper != "fit" and noise_model(self.hbni.model).correlated_frames:
            raise ValueError(
                f"mission.temper: the {self.hbni.model!r} model counts correlated frames itself (its fitted "
                f"frame correlation); a fixed temper is for hbni.model=paper or confusion, got {self.mission.temper!r}"
            )


ANNOTATIONS = ("video", "strip", "bag")


@dataclass
class StreamBlock:
    """``stream``: where frames come from, the saved models, the macro-observation process, the pictures."""

    source: Any = MISSING  # a ROS bag, a video file, a folder of frames or a camera index
    topic: Optional[str] = MISSING  # a bag's image topic (None: its only one)
    window: Optional[list[Optional[float]]] = MISSING  # [start, stop] seconds from a bag's start
    max_input_frames: Optional[int] = MISSING
    run: Optional[str] = MISSING  # a mission run directory; latest: the newest completed one under outputs/mission
    classifier: Optional[str] = MISSING
    posterior: Optional[str] = MISSING
    classes: Optional[list[str]] = MISSING
    temper: Optional[float] = MISSING
    threshold: float = MISSING
    max_frames: int = MISSING
    batch: int = MISSING
    annotate: list[str] = MISSING
    bag: Optional[bool] = MISSING  # write the ROS output bag (None: when the source is a bag)
    controller: Optional[str] = MISSING  # a saved JointController
    agent: int = MISSING
    observations: Any = MISSING  # class name -> controller observation name (null: the class names)

    def check(self, path: str) -> None:
        from pathlib import Path

        from classifiers.bags import is_bag

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
        bag = isinstance(source, str) and is_bag(source)
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
        if self.max_input_frames is not None:
            as_int("max_input_frames", self.max_input_frames, 1)
        if self.temper is not None:
            as_probability("temper", self.temper, allow_zero=False)
        as_probability("threshold", self.threshold, allow_zero=False)
        as_int("max_frames", self.max_frames, 1)
        as_int("batch", self.batch, 1)
        unknown = [a for a in self.annotate if a not in ANNOTATIONS]
        if unknown:
            raise ValueError(f"annotate: expected a subset of {list(ANNOTATIONS)}, got {list(self.annotate)}")
        if "bag" in self.annotate and not (bag if self.bag is None else self.bag):
            raise ValueError(
                "annotate: 'bag' puts the annotated frames into the output bag, which stream.bag does not write "
                "(null: only for a bag source)"
            )
        as_int("agent", self.agent, minimum=0)
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

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        loaded = "the stream loads a fitted posterior"
        out = {"seed": "the stream draws no random numbers", "hbni.model": loaded, "hbni.fit": loaded}
        out["hbni.hyperprior"] = loaded
        if cfg.stream.classifier is not None and cfg.stream.posterior is not None:
            out["stream.run"] = "stream.classifier and stream.posterior are both given"
        if cfg.stream.controller is None:
            out["stream.agent"] = "stream.controller is null: no robot's controller runs"
        return out

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return ()


@dataclass
class NoiseToyBlock:
    theta: list[float] = MISSING
    training_size: int = MISSING
    num_training_sets: int = MISSING
    num_trials: int = MISSING
    max_len: int = MISSING
    filter_draws: int = MISSING
    target: float = MISSING

    def check(self, path: str) -> None:
        _check_theta("theta", self.theta)
        for name in ("training_size", "num_training_sets", "num_trials", "max_len", "filter_draws"):
            as_int(name, getattr(self, name), 1)
        if self.training_size % len(self.theta):
            raise ValueError(
                f"training_size: expected a multiple of the {len(self.theta)} classes, got {self.training_size}"
            )
        if self.num_trials % self.num_training_sets:
            raise ValueError(
                f"num_trials: expected a multiple of num_training_sets ({self.num_training_sets}), got {self.num_trials}"
            )
        as_probability("target", self.target, allow_zero=False)


@dataclass
class NoiseMissionBlock:
    """``study.mission`` and ``study.photos``: the sizes of a condition (snapshots, sequences, frames)."""

    train_per_class: int = MISSING
    augment: int = MISSING
    calib_sequences: int = MISSING
    test_sequences: int = MISSING
    frames: int = MISSING

    def check(self, path: str) -> None:
        for name in ("train_per_class", "calib_sequences", "test_sequences", "frames"):
            as_int(name, getattr(self, name), 1)
        as_int("augment", self.augment, 0)


@dataclass
class NoiseStudy:
    """``study`` of the noise-model comparison."""

    models: list[str] = MISSING
    thresholds: list[float] = MISSING
    curve_thresholds: list[float] = MISSING
    cache_dir: Optional[str] = MISSING
    toy: NoiseToyBlock = field(default_factory=NoiseToyBlock)
    mission: NoiseMissionBlock = field(default_factory=NoiseMissionBlock)
    conditions: dict[str, Any] = MISSING
    images: Optional[str] = MISSING
    images_calibration: float = MISSING
    photos: Optional[NoiseMissionBlock] = MISSING

    def check(self, path: str) -> None:
        from hbni_pyro.variants import model_names

        if (
            not self.models
            or any(m not in model_names() for m in self.models)
            or len(set(self.models)) != len(self.models)
        ):
            raise ValueError(f"models: expected distinct models of {list(model_names())}, got {list(self.models)}")
        for name in ("thresholds", "curve_thresholds"):
            values = getattr(self, name)
            if not values:
                raise ValueError(f"{name}: expected at least one threshold")
            for t in values:
                as_probability(name, t, allow_zero=False)
        for name, overrides in self.conditions.items():
            _check_conditions(f"conditions.{name}", overrides)
        if not self.conditions and self.images is None and self.photos is None:
            raise ValueError("conditions: expected at least one imaging condition (or study.images, study.photos)")
        if not 0 < self.images_calibration < 1:
            raise ValueError(f"images_calibration: expected a share in (0, 1), got {self.images_calibration}")


@dataclass
class NoiseModels(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    study: NoiseStudy = field(default_factory=NoiseStudy)

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        out = {"hbni.model": "study.models names the models compared"}
        if cfg.study.images is None:
            out["study.images_calibration"] = "study.images is null: no image folder to split"
        return out

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return tuple(cfg.study.models)


@dataclass
class PlaceBlock:
    """An imaging place: overrides of the mission preset's conditions (``classifiers.data.MISSION``)."""

    conditions: dict[str, Any] = MISSING

    def check(self, path: str) -> None:
        _check_conditions("conditions", self.conditions)


@dataclass
class OldPlaceBlock(PlaceBlock):
    """``new_place.old``: the place the classifier's calibration comes from, its labelled sequences per class and
    the folds HBNI's stop is chosen on there."""

    sequences: int = MISSING
    stop_folds: int = MISSING

    def check(self, path: str) -> None:
        super().check(path)
        if as_int("stop_folds", self.stop_folds, 2) > as_int("sequences", self.sequences, 2):
            raise ValueError(f"stop_folds: expected at most sequences={self.sequences}, got {self.stop_folds}")


@dataclass
class HeldOutBankBlock:
    """``new_place.bank``: held-out sequences per class of the closed loop and the processes that build them."""

    sequences: int = MISSING
    workers: int = MISSING

    def check(self, path: str) -> None:
        as_int("sequences", self.sequences, 2)
        as_int("workers", self.workers, 0)


@dataclass
class NewPlacePhotosBlock:
    """``new_place.photos``: the same comparison on real photographs; the new camera's degradation overrides the
    ``"degraded"`` preset's fields (``classifiers.photos.PhotoConditions``)."""

    train_per_class: int = MISSING
    augment: int = MISSING
    old_sequences: int = MISSING
    test_sequences: int = MISSING
    conditions: dict[str, Any] = MISSING

    def check(self, path: str) -> None:
        import dataclasses

        from classifiers.photos import get_photo_conditions

        for name in ("train_per_class", "old_sequences", "test_sequences"):
            as_int(name, getattr(self, name), 2)
        as_int("augment", self.augment, 0)
        try:
            dataclasses.replace(get_photo_conditions("degraded"), **self.conditions)
        except TypeError as exc:
            raise ValueError(f"conditions: {exc}") from None


@dataclass
class NewPlaceBlock:
    """``new_place``: the classifier's training, the old and the new place, what the robot has there (``labelled``
    sequences per class, ``unlabelled`` streams in the class ``mix``), the adaptation's prior, the process, the
    planning tables and the closed loop."""

    train_per_class: int = MISSING
    augment: int = MISSING
    frames: int = MISSING
    threshold: float = MISSING
    calibration: str = MISSING
    old: OldPlaceBlock = field(default_factory=OldPlaceBlock)
    new: PlaceBlock = field(default_factory=PlaceBlock)
    labelled: list[int] = MISSING
    unlabelled: int = MISSING
    mix: list[float] = MISSING
    shift_sd: float = MISSING
    prevalence: float = MISSING
    generative_streams: int = MISSING
    cache_dir: str = MISSING
    bank: HeldOutBankBlock = field(default_factory=HeldOutBankBlock)
    bootstrap: BootstrapBlock = field(default_factory=BootstrapBlock)
    photos: Optional[NewPlacePhotosBlock] = MISSING

    def check(self, path: str) -> None:
        from decpomdp.domains.disaster_relief import CLASSES
        from hbni_pyro.frame_calibration import CALIBRATIONS

        for name in ("train_per_class", "frames", "generative_streams"):
            as_int(name, getattr(self, name), 1)
        as_int("augment", self.augment, 0)
        as_probability("threshold", self.threshold, allow_zero=False)
        as_choice("calibration", self.calibration, CALIBRATIONS)
        ks = [as_int("labelled", k, 0) for k in self.labelled]
        if not ks or ks != sorted(set(ks)):
            raise ValueError(f"labelled: expected distinct labelled sequences per class in rising order, got {ks}")
        if len(self.mix) != len(CLASSES) or any(not (math.isfinite(w) and w > 0) for w in self.mix):
            raise ValueError(f"mix: expected {len(CLASSES)} positive weights, one per class, got {list(self.mix)}")
        as_int("unlabelled", self.unlabelled, len(CLASSES))
        as_float("shift_sd", self.shift_sd, 0.0, low_open=True, high_open=True)
        as_float("prevalence", self.prevalence, 0.0, low_open=True, high_open=True)
        if not self.cache_dir.strip():
            raise ValueError("cache_dir: expected a directory for cached classifier outputs and banks")


@dataclass
class NewPlace(Root):
    classifier: Any = field(default_factory=ClassifierBlock)
    planner: Any = field(default_factory=PlannerBlock)  # plans perfect perception from scratch
    warm_planner: Any = field(default_factory=PlannerBlock)  # refines that plan on each variant's table
    domain: Any = field(default_factory=DisasterReliefBlock)
    new_place: NewPlaceBlock = field(default_factory=NewPlaceBlock)
    study: PlanningStudy = field(default_factory=PlanningStudy)

    @classmethod
    def unread(cls, cfg: DictConfig) -> dict[str, str]:
        return {
            "domain.perception": "the study gives each policy's domain its perception",
            "hbni.model": "the study fits the sequence model, the one hbni_pyro.adapt adapts",
        }

    @classmethod
    def noise_models(cls, cfg: DictConfig) -> tuple[str, ...]:
        return ("sequence",)


#: schema of each experiment, by its ``name``
SCHEMAS: dict[str, type] = {
    "hbni_toy": HBNIToy,
    "filtering_error": FilteringError,
    "macro_observation": MacroObservation,
    "perception_replay": PerceptionReplay,
    "package_delivery": PackageDeliveryExperiment,
    "disaster_relief": DisasterReliefExperiment,
    "dpomdp_benchmarks": DPOMDPBenchmarks,
    "mission": Mission,
    "mission_full": Mission,
    "stream": Stream,
    "noise_models": NoiseModels,
    "new_place": NewPlace,
}
