"""The mission end to end: pixels -> classifier outputs -> HBNI macro-observations -> Dec-POSMDP policy,
then the policy executed with the actual filter on held-out frames.

:func:`run` reads as its stages:

1. :func:`train_perception`: render training-condition snapshots of the six disaster-relief
   object types and train the :class:`~classifiers.FrameClassifier` head on them (crops and mirrors).
   :func:`start_bank`: the bank of held-out mission-condition sequences for the closed loop, from the
   cache or built in background processes while the next stages run.
2. :func:`classify_sequences`: render labelled calibration and held-out mission-condition
   sequences and classify every frame.
3. :func:`fit_noise`: fit HBNI on the calibration outputs (the sequence model: each sequence's look and
   the correlation of its consecutive frames); a frame-level model also gets its likelihood temper fitted on
   the same sequences (:func:`hbni_pyro.fit_temper`: their frames are correlated, not i.i.d.).
4. :func:`characterize_processes`: run HBNI, SSBF and max-of-mean macro-observation processes
   (threshold, frame budget) on the held-out streams and tabulate each one's
   ``P(label, frames | true class)``: the :class:`~hbni_pyro.MacroObservationModel` of the
   "infer with 95 % confidence" MA (the empirical planning model). :func:`characterize_generative`:
   the same processes run on streams simulated from HBNI's fitted posterior predictive (the
   generative planning model, the default); :func:`planning_models` gives each variant the one
   ``mission.planning_model`` names, and HBNI also the other one (``hbni_<other>``).
5. :func:`plan`: plug each model (and perfect perception) into the disaster-relief domain and search a
   controller with the planner (no hand-written controller): perfect perception from scratch (settings
   ``planner``: the cold-start planner tuned for the mission, or ``planner=gdice`` for the paper's G-DICE),
   then each perception variant from that plan (``warm_start: true``, settings ``warm_planner``) or from
   scratch too (``warm_start: false``). Each controller, and the greedy controller itself, is
   re-evaluated on independent rollouts: the planned value.
6. :func:`execute_closed_loop`: every saved controller run in the domain with each "infer" MA
   answered by that variant's process on a fresh held-out stream of the true class (the bank's; a
   generative table's policy also the characterisation sequences'; HBNI's, when its value test lacks
   power, also the bank's next sequences, rendered only as far as its process reads them:
   :mod:`experiments.steps.on_demand`): the executed value, and its gap to the planned one in
   standard errors.

Writes ``metrics.json``, ``report.md`` with the figures ``values.png``, ``confusion.png``,
``frames.png``, ``learning_curves.png`` and ``closed_loop.png``, and every fitted artefact
(``artifacts.json``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import resource
import time
from pathlib import Path
from typing import Any, NamedTuple

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf
from tqdm.auto import tqdm

import hbni_pyro
from classifiers import FrameClassifier
from classifiers.data import get_conditions
from decpomdp import JointController
from decpomdp.domains.disaster_relief import CLASSES, greedy_controller
from decpomdp.search import PlannerConfig
from experiments import mission_report
from experiments.artifacts import save_artifact
from experiments.common import beats, ratio, save_figure
from experiments.report import write_report
from experiments.schemas.studies import MISSION_VARIANTS
from experiments.steps import closed_loop, honesty
from experiments.steps.bank import BankBuild, BankSpec
from experiments.steps.on_demand import OnDemandStreams
from experiments.steps.noise import fit_labelled, stop_folds
from experiments.steps.perception import sequence_outputs, train_classifier
from experiments.steps.planning import delivery_rates, run_planner, score
from hbni_infra.streams import stream_seed
from hbni_infra.threads import threads


class StageClock:
    """Wall and CPU seconds of the main process per stage; a stage lasts until the next one starts."""

    def __init__(self, progress: bool) -> None:
        self.progress = progress
        self.marks: list[tuple[str, float, float]] = []  # (stage, wall, CPU) at its start

    def start(self, stage: str, message: str) -> None:
        """Begin ``stage`` (ending the previous one) and :meth:`say` ``message``."""
        self.marks.append((stage, time.perf_counter(), time.process_time()))
        self.say(message)

    def say(self, message: str) -> None:
        """Print ``message`` when showing progress."""
        if self.progress:
            tqdm.write(f"[mission] {message}")

    def seconds(self) -> dict[str, dict[str, float]]:
        """``{stage: {"wall": s, "cpu": s}}`` up to now."""
        ends = [mark[1:] for mark in self.marks[1:]] + [(time.perf_counter(), time.process_time())]
        return {
            stage: {"wall": wall_end - wall, "cpu": cpu_end - cpu}
            for (stage, wall, cpu), (wall_end, cpu_end) in zip(self.marks, ends)
        }


class Settings(NamedTuple):
    """The mission's validated settings (checked before any work starts)."""

    seed: int
    progress: bool
    variants: list[str]
    temper: float | None  # None: fit it on the calibration sequences
    overrides: dict[str, Any]  # imaging overrides of the `mission` preset
    frames: int
    loop: closed_loop.LoopSettings  # planning model, generative streams, held-out bank
    clock: StageClock


class Outputs(NamedTuple):
    """Classifier outputs, float64, columns in ``CLASSES`` order."""

    calibration: torch.Tensor  # (C, calib_sequences, frames, C)
    held_out: torch.Tensor  # (C, char_sequences, frames, C)


class Noise(NamedTuple):
    """The fitted noise model and its temper (``{"value", "fitted", ...}``), and the calibrated peer's frame
    calibration and evidence weight (``None`` when it is not among the variants)."""

    posterior: hbni_pyro.HBNIPosterior
    temper: dict[str, Any]
    peer: Peer | None = None
    stop: dict[str, Any] | None = None  # HBNI's stopping confidence: {"value", "fitted", ...}; None: the threshold


class Peer(NamedTuple):
    """The calibrated peer fitted on the calibration sequences: the per-frame map and its filter's temper."""

    calibration: hbni_pyro.FrameCalibration
    temper: float
    log_score: list[float]

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable: the map's kind and fit, the temper."""
        return {"kind": self.calibration.kind, **self.calibration.info, "temper": self.temper}


def run(cfg: DictConfig, run_dir: Path) -> dict:
    settings = read_settings(cfg)
    clf = train_perception(cfg, settings, run_dir)
    bank = start_bank(clf, settings, run_dir)
    try:
        outputs = classify_sequences(clf, cfg, settings)
        noise = fit_noise(outputs.calibration, cfg, settings, run_dir)
        empirical = characterize_processes(noise, outputs.held_out, cfg, settings, run_dir)
        generative = characterize_generative(noise, cfg, settings, run_dir)
        models = planning_models(empirical, generative, settings)
        results, histories = plan(models, cfg, settings, run_dir, bank)
        settings.clock.start("bank_wait", "waiting for the held-out bank")
        banked = bank.result(settings.progress)
        threads = int(cfg.study.threads)  # on one, this process renders: it would only wait on a worker it must start
        with OnDemandStreams(
            bank.spec, clf, run_dir / "classifier.safetensors", threads if threads > 1 else 0, settings.progress
        ) as more:
            reliability = execute_closed_loop(
                banked, outputs.held_out, noise, models, results, cfg, settings, run_dir, more
            )
    finally:
        bank.cancel()
    return write_outputs(run_dir, cfg, settings, outputs, noise, models, results, histories, bank, reliability)


def read_settings(cfg: DictConfig) -> Settings:
    """The mission's settings from its config (already checked against its schema, ``experiments.schemas``)."""
    st = cfg.mission
    overrides = OmegaConf.to_container(st.conditions) if st.conditions else {}
    variants = list(cfg.perception) if isinstance(cfg.perception, ListConfig) else [str(cfg.perception)]
    temper = None if st.temper == "fit" else float(st.temper)
    return Settings(
        int(cfg.seed),
        bool(cfg.progress),
        variants,
        temper,
        overrides,
        int(st.frames),
        closed_loop.read_loop_settings(cfg),
        StageClock(bool(cfg.progress)),
    )


def train_perception(cfg: DictConfig, settings: Settings, run_dir: Path) -> FrameClassifier:
    """Stage 1: the frame classifier, trained on training-condition snapshots (saved as ``classifier``)."""
    settings.clock.start("train", "1/6 training the frame classifier on training-condition snapshots")
    st = cfg.mission
    clf = train_classifier(
        cfg.classifier,
        CLASSES,
        int(st.train_per_class),
        int(st.augment),
        stream_seed(settings.seed, "train"),
        settings.progress,
        int(cfg.study.threads),
    )
    save_artifact(run_dir, "classifier", clf)
    return clf


def start_bank(clf: FrameClassifier, settings: Settings, run_dir: Path) -> BankBuild:
    """Stage 1b: the held-out bank (its own random stream, ``"bank"``, apart from calibration and characterisation):
    loaded from ``mission.bank.cache_dir``, or rendered and classified by background workers."""
    loop = settings.loop
    spec = BankSpec(
        tuple(CLASSES),
        get_conditions("mission", **settings.overrides),
        stream_seed(settings.seed, "bank"),
        loop.bank_sequences,
        settings.frames,
    )
    bank = BankBuild(spec, clf, run_dir / "classifier.safetensors", loop.cache_dir, loop.workers)
    how = "found in the cache" if bank.cached else f"building with {loop.workers} background worker(s)"
    settings.clock.say(f"held-out bank of {loop.bank_sequences} sequences per class: {how} ({bank.path})")
    return bank


def classify_sequences(clf: FrameClassifier, cfg: DictConfig, settings: Settings) -> Outputs:
    """Stage 2: classifier outputs of the calibration and held-out mission-condition sequences."""
    settings.clock.start("classify", "2/6 classifying mission-condition frames")
    st, seed, progress = cfg.mission, settings.seed, settings.progress
    mission = get_conditions("mission", **settings.overrides)
    workers = int(cfg.study.threads)
    calib = sequence_outputs(
        clf,
        CLASSES,
        int(st.calib_sequences),
        settings.frames,
        mission,
        stream_seed(seed, "calibration"),
        progress,
        "calibration",
        workers,
    )[0]
    held = sequence_outputs(
        clf,
        CLASSES,
        int(st.char_sequences),
        settings.frames,
        mission,
        stream_seed(seed, "held-out"),
        progress,
        "held-out",
        workers,
    )[0]
    return Outputs(calib.double(), held.double())


def fit_noise(calib: torch.Tensor, cfg: DictConfig, settings: Settings, run_dir: Path) -> Noise:
    """Stage 3: HBNI fitted on the labelled calibration outputs (saved as ``posterior``), and its temper."""
    settings.clock.start("fit", "3/6 fitting HBNI and its frame-correlation temper on labelled calibration outputs")
    posterior = fit_labelled(
        calib, cfg.hbni, stream_seed(settings.seed, "fit"), settings.progress, class_names=list(CLASSES)
    )
    save_artifact(run_dir, "posterior", posterior)
    peer = fit_peer(calib, cfg, settings, run_dir) if "calibrated" in settings.variants else None
    M, frames = len(CLASSES), settings.frames
    truth = torch.arange(M).repeat_interleave(calib.shape[1])
    streams = calib.reshape(-1, frames, M)
    if settings.temper is not None:
        temper = {"value": settings.temper, "fitted": False}
    elif posterior.noise_model.sequences:  # the model integrates each sequence's look out: no temper to fit
        temper = {"value": 1.0, "fitted": False, "needed": False}
    else:
        fitted = hbni_pyro.fit_temper(posterior, streams, truth, cfg.hbni.filter.mode)
        temper = {
            "value": fitted.temper,
            "fitted": True,
            "grid": fitted.grid.tolist(),
            "log_score": fitted.log_score.tolist(),
        }
    threshold = float(cfg.mission.threshold)
    stop: dict[str, Any] = {"value": threshold, "fitted": False}
    if cfg.mission.hbni_stop == "calibrated":
        folds = int(cfg.mission.stop_folds)
        settings.clock.say(f"choosing HBNI's stop on {folds} held-out folds of the calibration sequences")
        held_out = stop_folds(
            calib, cfg.hbni, settings.seed, "fit", folds=folds, temper=temper["value"], progress=settings.progress
        )
        fitted_stop = hbni_pyro.fit_stop_threshold(held_out, None, None, threshold, frames)
        stop = {"fitted": True, "folds": folds, **fitted_stop._asdict(), "value": fitted_stop.stop}
        del stop["stop"]
    return Noise(posterior, temper, peer, stop)


def fit_peer(calib: torch.Tensor, cfg: DictConfig, settings: Settings, run_dir: Path) -> Peer:
    """The calibrated peer on the same labelled calibration outputs ``(C, S, F, C)`` HBNI gets: the per-frame map
    ``mission.calibration`` (saved as ``calibration``), then SSBF's evidence weight for correlated frames fitted on
    the calibration sequences as a frame-level HBNI model's temper is (:func:`hbni_pyro.fit_temper`)."""
    M, frames = len(CLASSES), settings.frames
    labels = torch.arange(M).view(-1, 1, 1).expand(calib.shape[:3])
    calibration = hbni_pyro.fit_frame_calibration(calib, labels, str(cfg.mission.calibration), class_names=CLASSES)
    save_artifact(run_dir, "calibration", calibration)
    truth = torch.arange(M).repeat_interleave(calib.shape[1])
    peer = hbni_pyro.make_filter("calibrated", calibration=calibration)
    fitted = hbni_pyro.fit_temper(peer, calib.reshape(-1, frames, M), truth)
    return Peer(calibration, fitted.temper, fitted.log_score.tolist())


def characterize_processes(
    noise: Noise, held: torch.Tensor, cfg: DictConfig, settings: Settings, run_dir: Path
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """Stage 4: each variant's macro-observation table on the held-out streams (saved as ``macro_<variant>``)."""
    settings.clock.start("characterize", "4/6 characterising the macro-observation processes on held-out streams")
    M = len(CLASSES)
    streams = held.reshape(-1, settings.frames, M)
    truth = torch.arange(M).repeat_interleave(held.shape[1])
    models = {}
    for name, process in build_processes(noise, cfg, settings).items():
        models[name] = hbni_pyro.tabulate(process, streams, truth)
        save_artifact(run_dir, f"macro_{name}", models[name])
    return models


def build_processes(noise: Noise, cfg: DictConfig, settings: Settings) -> dict[str, hbni_pyro.MacroObservationProcess]:
    """Each variant's macro-observation process: its filter, ``mission.threshold`` (HBNI: the stopping confidence
    that keeps that promise on the calibration sequences, with ``mission.hbni_stop=calibrated``) and the frame
    budget."""
    threshold = float(cfg.mission.threshold)
    stops = {"hbni": noise.stop["value"] if noise.stop else threshold}
    options: dict[str, dict[str, Any]] = {"hbni": {"mode": cfg.hbni.filter.mode, "temper": noise.temper["value"]}}
    if noise.peer is not None:
        options["calibrated"] = {"calibration": noise.peer.calibration, "temper": noise.peer.temper}
    return {
        name: hbni_pyro.MacroObservationProcess(
            hbni_pyro.make_filter(name, noise.posterior, num_classes=len(CLASSES), **options.get(name, {})),
            threshold=stops.get(name, threshold),
            max_frames=settings.frames,
        )
        for name in settings.variants
    }


def characterize_generative(
    noise: Noise, cfg: DictConfig, settings: Settings, run_dir: Path
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """Stage 4b: the generative planning model of the variants that need it (all of them when
    ``mission.planning_model=generative``, else HBNI when ``mission.compare_planning_models``): each
    process run on ``mission.generative_streams`` streams per class drawn from the posterior predictive
    of the fitted ``hbni.model`` (a posterior draw per stream; its frames i.i.d. given it under the
    frame-level models, sharing one look under ``sequence``, about which consecutive frames correlate as in the
    calibration sequences: :attr:`hbni_pyro.HBNIPosterior.frame_correlation`); saved as
    ``macro_<variant>_generative``."""
    loop = settings.loop
    needed = (
        settings.variants
        if loop.planning_model == "generative"
        else ([v for v in settings.variants if v == "hbni"] if loop.compare_planning_models else [])
    )
    if needed:
        settings.clock.start(
            "characterize_generative",
            f"4/6 characterising {', '.join(needed)} on streams simulated from the fitted HBNI model",
        )
    processes = build_processes(noise, cfg, settings)
    models = {}
    for name in needed:
        models[name] = hbni_pyro.characterize(
            processes[name], noise.posterior, loop.generative_streams, stream_seed(settings.seed, "generative", name)
        )
        save_artifact(run_dir, f"macro_{name}_generative", models[name])
    return models


def planning_models(
    empirical: dict[str, hbni_pyro.MacroObservationModel],
    generative: dict[str, hbni_pyro.MacroObservationModel],
    settings: Settings,
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """What each policy plans on: every variant on ``mission.planning_model``, and HBNI also on the other model
    (entry ``hbni_<other>``) when ``mission.compare_planning_models``."""
    loop = settings.loop
    tables = {"empirical": empirical, "generative": generative}
    models = dict(tables[loop.planning_model])
    other = closed_loop.other_model(loop.planning_model)
    if loop.compare_planning_models and "hbni" in tables[other]:
        models[f"hbni_{other}"] = tables[other]["hbni"]
    return models


def entry_planning(settings: Settings, name: str) -> str:
    """The planning model of policy ``name`` (``exact`` for perfect perception)."""
    if name == "perfect":
        return "exact"
    return settings.loop.planning_model if name in MISSION_VARIANTS else name.rsplit("_", 1)[1]


def _entry_variant(name: str) -> str:
    """The perception variant of a planned policy: ``hbni_generative`` -> ``hbni``."""
    return name if name in MISSION_VARIANTS else name.rsplit("_", 1)[0]


def planners(cfg: DictConfig) -> tuple[PlannerConfig, PlannerConfig | None]:
    """The planner's settings (``planner``) and those of the warm starts from the perfect-perception plan
    (``warm_planner``; ``None`` without ``warm_start``)."""
    return instantiate(cfg.planner), instantiate(cfg.warm_planner) if cfg.warm_start else None


def plan(
    models: dict[str, hbni_pyro.MacroObservationModel],
    cfg: DictConfig,
    settings: Settings,
    run_dir: Path,
    bank: BankBuild | None = None,
) -> tuple[dict[str, dict], dict[str, dict]]:
    """Stage 5: a controller per perception variant and for perfect perception (saved as
    ``controller_<variant>``): perfect perception planned from scratch with ``planner``, each variant from that
    plan with ``warm_planner`` (or from scratch too without ``warm_start``), each re-evaluated on independent
    rollouts beside the greedy controller.

    Rollouts run on ``study.threads`` threads, less the cores ``bank``'s background workers still hold (a
    parallel loop with a contended core waits for it); a seed gives the same results on any thread count.

    Returns the score entry and the search history of every variant.
    """
    settings.clock.start("plan", "5/6 planning on the disaster-relief domain (no hand-written controller)")
    planner, warm = planners(cfg)
    study, seed, reeval = cfg.study, settings.seed, int(cfg.study.reeval_rollouts)
    results: dict[str, Any] = {}
    histories = {}
    start = None  # with warm_start: the perfect-perception plan every perception variant starts from

    def free() -> int:
        """The threads the bank's workers leave, asked at every rollout call: all of them once it is built."""
        return max(1, int(study.threads) - (bank.workers if bank is not None and bank.building else 0))

    for name in ("perfect", *models):
        with threads(free):
            env = instantiate(cfg.domain, perception=None if name == "perfect" else models[name])
            greedy = greedy_controller(env.num_agents)
            result, best, entry = run_planner(
                env,
                planner if start is None else warm,
                bool(study.shared_controller),
                stream_seed(seed, "plan", name),
                settings.progress,
                reeval,
                init=start,
            )
            entry["search_seconds"] = entry.pop("seconds")
            entry["started_from"] = "scratch" if start is None else "perfect"
            if warm is not None and name == "perfect":
                start = result.best
            save_artifact(run_dir, f"controller_{name}", best)
            hand = score(env, greedy, reeval, stream_seed(seed, "greedy", name))
            entry["greedy"] = {
                key: hand[key] for key in ("value", "stderr", "delivered_per_rollout", "wrong_per_rollout")
            }
            entry.update(delivery_rates(entry))
            if name != "perfect":
                entry["macro_accuracy"] = models[name].accuracy.tolist()
                entry["macro_mean_frames"] = models[name].mean_frames.tolist()
                entry["macro_timed_out"] = models[name].timed_out.tolist()
            results[name] = entry
            histories[name] = result.history
    return results, histories


def execute_closed_loop(
    bank: torch.Tensor,
    held: torch.Tensor,
    noise: Noise,
    models: dict[str, hbni_pyro.MacroObservationModel],
    results: dict[str, dict],
    cfg: DictConfig,
    settings: Settings,
    run_dir: Path,
    more: OnDemandStreams,
) -> plt.Figure | None:
    """Stage 6: each saved controller executed with its variant's actual process on fresh held-out streams
    (perfect perception: in its own domain again); adds ``executed`` to every result entry, with the stream
    standard errors of the planned value (an empirical table of ``held``'s size) and of the executed one, by
    bootstrap from the pooled held-out and bank sequences, the distribution check of the entry's table against
    its process on those streams and the value test.

    A policy planned on an empirical table runs on the bank alone (its table was tabulated on ``held``); one
    planned on a simulated table saw no recorded sequence, so it runs on ``held`` and the bank together, which
    makes its value test more powerful at no cost. An entry of ``mission.bank.powered`` whose value test has
    less than its target power is executed again on more held-out sequences, rendered by ``more``
    (:func:`_powered`). Returns the reliability diagram of every process on the bank (``None`` without
    variants)."""
    settings.clock.start("closed_loop", "6/6 executing every policy in closed loop on the held-out bank")
    pooled = torch.cat([held.double(), bank.double()], dim=1)  # (C, held + bank sequences, F, C)
    processes = build_processes(noise, cfg, settings)
    on_pool = {  # each variant's replay of every pooled stream (each run once)
        name: hbni_pyro.StreamReplay(p, *closed_loop.as_streams(pooled)) for name, p in processes.items()
    }
    loop = _Loop(held.shape[1], models, results, cfg, settings)
    for name in tqdm(list(results), desc="closed loop", disable=not settings.progress):
        controller = JointController.load(run_dir / f"controller_{name}.safetensors")
        if name == "perfect":
            seed = stream_seed(settings.seed, "execute", name)
            executed = closed_loop.execute(controller, None, cfg.domain, int(cfg.study.reeval_rollouts), seed)
            results[name]["executed"] = closed_loop.summarise(results[name], executed, None)
            continue
        variant = _entry_variant(name)
        entry = _executed(name, controller, on_pool[variant], loop)
        if name in settings.loop.powered.entries:
            entry = _powered(name, controller, entry, on_pool, processes[variant], more, loop)
        results[name]["executed"] = entry
    for name, replay in on_pool.items():
        results[name]["held_out_process"] = closed_loop.held_out_checks(replay, float(cfg.mission.threshold))
    return (
        honesty.reliability_figure(
            processes, *closed_loop.as_streams(bank), mission_report.LABELS, float(cfg.mission.threshold)
        )
        if processes
        else None
    )


class _Loop(NamedTuple):
    """What every closed-loop entry reads: the characterisation sequences per class, the planning models, the
    planned results, the config and the settings."""

    held: int
    models: dict[str, hbni_pyro.MacroObservationModel]
    results: dict[str, dict]
    cfg: DictConfig
    settings: Settings


def _powered(
    name: str,
    controller: JointController,
    entry: dict[str, Any],
    on_pool: dict[str, hbni_pyro.StreamReplay],
    process: hbni_pyro.MacroObservationProcess,
    more: OnDemandStreams,
    loop: _Loop,
) -> dict[str, Any]:
    """Policy ``name``'s closed-loop ``entry``, executed again on more held-out sequences while its value test has
    less than the target power: each step adds the bank's next sequences, rendered by ``more`` only as far as the
    process reads them, up to ``margin`` times what the power calculation asks for but at most doubling the
    sequences (the calculation rests on a noisy estimate of the streams' variance), never past
    ``max_sequences`` per class. Updates the variant's entry in ``on_pool``."""
    held, settings = loop.held, loop.settings
    powered, variant = settings.loop.powered, _entry_variant(name)
    first = held if entry_planning(settings, name) == "empirical" else 0
    added, rendered = 0, []
    while entry["value_test"]["power"] < honesty.TARGET_POWER:
        have = int(on_pool[variant].streams_per_class[0])
        want = first + math.ceil(powered.margin * min(entry["value_test"]["sequences_for_target"], 1e9))
        count = min(want, 2 * have, powered.max_sequences) - have
        if count <= 0:
            break
        settings.clock.say(
            f"{name}: value test power {entry['value_test']['power']:.2f} on {have - first} held-out sequences "
            f"per class; rendering {count} more, each as far as its process reads it"
        )
        on_pool[variant], frames = more.replay(process, on_pool[variant], have - held, count)  # the bank's next
        added, rendered = added + count, rendered + [frames]
        entry = _executed(name, controller, on_pool[variant], loop)
    if added:
        frames = torch.cat(rendered, dim=1).double()
        entry["on_demand"] = {"sequences_per_class": added, "mean_frames_rendered": float(frames.mean())}
    return entry


def _executed(name: str, controller: JointController, pool: hbni_pyro.StreamReplay, loop: _Loop) -> dict[str, Any]:
    """The closed-loop entry of policy ``name`` on ``pool``, a replay of as many sequences of every class (in
    ``closed_loop.as_streams`` order), of which the first ``loop.held`` are the characterisation sequences (not
    fresh to an empirical table)."""
    held, models, results, cfg, settings = loop
    C, per_class = pool.num_classes, int(pool.streams_per_class[0])
    seed = stream_seed(settings.seed, "execute", name)
    empirical = entry_planning(settings, name) == "empirical"
    first = held if empirical else 0
    fresh = per_class - first
    replay = closed_loop.resampled(pool, C, per_class, torch.arange(first, per_class))
    executed = closed_loop.execute(controller, replay, cfg.domain, int(cfg.study.reeval_rollouts), seed)
    resample = functools.partial(closed_loop.resampled, pool, C, per_class)
    boot = settings.loop.bootstrap
    on_bank = closed_loop.stream_stderr(
        controller, resample, per_class, fresh, cfg.domain, boot, stream_seed(settings.seed, "bootstrap", "bank", name)
    )
    on_table = (
        0.0
        if not empirical
        else closed_loop.stream_stderr(
            controller,
            resample,
            per_class,
            held,
            cfg.domain,
            boot,
            stream_seed(settings.seed, "bootstrap", "table", name),
        )
    )
    entry = closed_loop.summarise(results[name], executed, replay, on_table, on_bank)
    entry["sequences_per_class"] = fresh
    table_streams = held if empirical else settings.loop.generative_streams
    entry["distribution_check"] = honesty.distribution_check(
        models[name], replay, table_streams, stream_seed(settings.seed, "honesty", name)
    )
    entry["value_test"] = honesty.value_test(results[name], entry, fresh)
    return entry


def write_outputs(
    run_dir: Path,
    cfg: DictConfig,
    settings: Settings,
    outputs: Outputs,
    noise: Noise,
    models: dict[str, hbni_pyro.MacroObservationModel],
    results: dict[str, dict],
    histories: dict[str, dict],
    bank: BankBuild,
    reliability: plt.Figure | None,
) -> dict:
    """Figures, ``report.md``; returns the metrics."""
    planner, warm = planners(cfg)
    figures = {
        "values.png": mission_report.value_figure(results),
        "confusion.png": mission_report.confusion_figure(models),
        "frames.png": mission_report.frames_figure(models),
        "learning_curves.png": mission_report.curves_figure(
            histories,
            {name: results["perfect"]["rollouts"] for name, r in results.items() if r.get("started_from") == "perfect"},
        ),
        "closed_loop.png": closed_loop.figure(results, mission_report.LABELS),
    }
    if reliability is not None:
        figures["reliability.png"] = reliability
    for file, fig in figures.items():
        save_figure(fig, run_dir / file)
    st = cfg.mission
    calib, held = outputs
    metrics = {
        "classes": CLASSES,
        "variants": results,
        "acceptance": _acceptance(results),
        "closed_loop": {
            "acceptance": closed_loop.acceptance(results),
            "planning": {name: entry_planning(settings, name) for name in results},
            "bank": {
                "path": str(bank.path),
                "cached": bank.cached,
                "seed": bank.spec.seed,
                "sequences_per_class": bank.spec.sequences,
                "held_out_sequences_per_class": int(held.shape[1]),
                "frames": bank.spec.frames,
            },
        },
        "classifier_frame_accuracy": _frame_accuracy(held),
        "conditions": {"preset": "mission", "overrides": settings.overrides},
        "hbni_temper": noise.temper,
        "hbni_stop": noise.stop,
        "calibrated_peer": None if noise.peer is None else noise.peer.summary(),
        "hbni_frame_correlation": noise.posterior.frame_correlation,
        "theta_summary": {k: v for k, v in noise.posterior.summary().items() if k.startswith("theta")},
        "planner": dataclasses.asdict(planner),
        "warm_planner": None if warm is None else dataclasses.asdict(warm),
        "wrong_penalty": float(cfg.domain.wrong_penalty),
        "frame_period": float(cfg.domain.frame_period),
        "sizes": {
            "train_snapshots_per_class": int(st.train_per_class),
            "calibration_frames": int(calib[..., 0].numel()),
            "held_out_streams": int(held.shape[0] * held.shape[1]),
            "generative_streams_per_class": settings.loop.generative_streams,
            "frames_per_stream": settings.frames,
        },
        "cpu_seconds": _cpu_seconds(),
        "stage_seconds": settings.clock.seconds(),
    }
    cl = metrics["closed_loop"]
    section = closed_loop.report_lines(results, mission_report.LABELS, cl["planning"], cl["bank"])
    section += honesty.report_lines(results, mission_report.LABELS, CLASSES)
    cpu = metrics["cpu_seconds"]
    section.append(
        f"CPU time of this run: {cpu['main']:.0f} s in the main process, {cpu['workers']:.0f} s in bank workers. "
        "Per stage of the main process (wall / CPU s): "
        + ", ".join(f"{stage} {t['wall']:.0f} / {t['cpu']:.0f}" for stage, t in metrics["stage_seconds"].items())
        + "."
    )
    write_report(run_dir / "report.md", mission_report.report(metrics, list(figures)) + "\n" + "\n".join(section))
    return metrics


def _cpu_seconds() -> dict[str, float]:
    """CPU seconds (user + system) so far of this process and of its finished child processes (bank workers)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"main": own.ru_utime + own.ru_stime, "workers": children.ru_utime + children.ru_stime}


def _frame_accuracy(outputs: torch.Tensor) -> dict[str, float]:
    return {name: float((outputs[c].argmax(-1) == c).double().mean()) for c, name in enumerate(CLASSES)}


def _acceptance(results: dict[str, dict]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "hbni" not in results:
        return out
    h = results["hbni"]
    out["hbni_over_perfect"] = ratio(h["value"], results["perfect"]["value"])
    for other in ("calibrated", "ssbf", "max_of_mean"):
        if other in results:
            o = results[other]
            out[f"hbni_beats_{other}_outside_stderr"] = beats(h, o)
            out[f"hbni_minus_{other}_in_stderr"] = ratio(
                h["value"] - o["value"], (h["stderr"] ** 2 + o["stderr"] ** 2) ** 0.5
            )
    if "ssbf" in results:
        out["hbni_wrong_rate_below_ssbf"] = h["wrong_rate"] < results["ssbf"]["wrong_rate"]
    return out
