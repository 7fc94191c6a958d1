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
6. :func:`~experiments.steps.execution.execute_closed_loop`: every saved controller run in the domain with each
   "infer" MA answered by that variant's process (:func:`build_processes`) on a fresh held-out stream of the true
   class (the bank's; a generative table's policy also the characterisation sequences'; HBNI's, when its value
   test lacks power, also the bank's next sequences, rendered only as far as its process reads them:
   :mod:`experiments.steps.on_demand`): the executed value, and its gap to the planned one in standard errors.

Every stage reads the typed :class:`~experiments.schemas.mission_study.Mission` settings the entry point built, and
the :class:`~experiments.runs.clock.StageClock` that times the stages.

Writes ``metrics.json``, ``report.md`` with the figures ``values.png``, ``confusion.png``,
``frames.png``, ``learning_curves.png`` and ``closed_loop.png``, and every fitted artefact
(``artifacts.json``).
"""

from __future__ import annotations

import dataclasses
import resource
from pathlib import Path
from typing import Any, NamedTuple

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

import hbni_pyro
from classifiers import FrameClassifier
from classifiers.data import get_conditions
from decpomdp.domains.disaster_relief import CLASSES, greedy_controller
from decpomdp.search import PlannerConfig
from experiments.reports import mission_report
from experiments.runs.artifacts import save_artifact
from experiments.runs.clock import StageClock
from experiments.runs.outputs import save_figure, write_report
from experiments.schemas.mission_study import Mission
from experiments.steps import closed_loop, honesty
from experiments.steps.bank import BankBuild, BankSpec
from experiments.steps.classification import sequence_outputs, train_study_classifier
from experiments.steps.execution import entry_planning, execute_closed_loop
from experiments.steps.noise import fit_labelled, stop_folds
from experiments.steps.on_demand import OnDemandStreams
from experiments.steps.planning import delivery_rates, run_planner, score
from hbni_infra.streams import stream_seed
from hbni_infra.threads import threads


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


def run(settings: Mission, run_dir: Path) -> dict:
    clock = StageClock("mission", settings.progress)
    clf = train_perception(settings, clock, run_dir)
    bank = start_bank(clf, settings, clock, run_dir)
    try:
        outputs = classify_sequences(clf, settings, clock)
        noise = fit_noise(outputs.calibration, settings, clock, run_dir)
        empirical = characterize_processes(noise, outputs.held_out, settings, clock, run_dir)
        generative = characterize_generative(noise, settings, clock, run_dir)
        models = planning_models(empirical, generative, settings)
        results, histories = plan(models, settings, clock, run_dir, bank)
        clock.start("bank_wait", "waiting for the held-out bank")
        banked = bank.result(settings.progress)
        threads = settings.study.threads  # on one, this process renders: it would only wait on a worker it must start
        with OnDemandStreams(
            bank.spec, clf, run_dir / "classifier.safetensors", threads if threads > 1 else 0, settings.progress
        ) as more:
            processes = build_processes(noise, settings)
            reliability = execute_closed_loop(
                banked, outputs.held_out, processes, models, results, settings, clock, run_dir, more
            )
    finally:
        bank.cancel()
    return write_outputs(run_dir, settings, clock, outputs, noise, models, results, histories, bank, reliability)


def train_perception(settings: Mission, clock: StageClock, run_dir: Path) -> FrameClassifier:
    """Stage 1: the frame classifier, trained on training-condition snapshots (saved as ``classifier``)."""
    clock.start("train", "1/6 training the frame classifier on training-condition snapshots")
    return train_study_classifier(settings, settings.mission, list(CLASSES), run_dir)


def start_bank(clf: FrameClassifier, settings: Mission, clock: StageClock, run_dir: Path) -> BankBuild:
    """Stage 1b: the held-out bank (its own random stream, ``"bank"``, apart from calibration and characterisation):
    loaded from ``mission.bank.cache_dir``, or rendered and classified by background workers."""
    st = settings.mission
    spec = BankSpec(
        tuple(CLASSES),
        get_conditions("mission", **st.overrides),
        stream_seed(settings.seed, "bank"),
        st.bank.sequences,
        st.frames,
    )
    bank = BankBuild(spec, clf, run_dir / "classifier.safetensors", st.bank.cache_path, st.bank.workers)
    how = "found in the cache" if bank.cached else f"building with {st.bank.workers} background worker(s)"
    clock.say(f"held-out bank of {st.bank.sequences} sequences per class: {how} ({bank.path})")
    return bank


def classify_sequences(clf: FrameClassifier, settings: Mission, clock: StageClock) -> Outputs:
    """Stage 2: classifier outputs of the calibration and held-out mission-condition sequences."""
    clock.start("classify", "2/6 classifying mission-condition frames")
    st, seed, progress = settings.mission, settings.seed, settings.progress
    mission = get_conditions("mission", **st.overrides)
    workers = settings.study.threads
    calib = sequence_outputs(
        clf,
        CLASSES,
        st.calib_sequences,
        st.frames,
        mission,
        stream_seed(seed, "calibration"),
        progress,
        "calibration",
        workers,
    )[0]
    held = sequence_outputs(
        clf,
        CLASSES,
        st.char_sequences,
        st.frames,
        mission,
        stream_seed(seed, "held-out"),
        progress,
        "held-out",
        workers,
    )[0]
    return Outputs(calib.double(), held.double())


def fit_noise(calib: torch.Tensor, settings: Mission, clock: StageClock, run_dir: Path) -> Noise:
    """Stage 3: HBNI fitted on the labelled calibration outputs (saved as ``posterior``), and its temper."""
    clock.start("fit", "3/6 fitting HBNI and its frame-correlation temper on labelled calibration outputs")
    st = settings.mission
    posterior = fit_labelled(
        calib, settings.hbni, stream_seed(settings.seed, "fit"), settings.progress, class_names=list(CLASSES)
    )
    save_artifact(run_dir, "posterior", posterior)
    peer = fit_peer(calib, settings, run_dir) if "calibrated" in settings.variants else None
    M, frames = len(CLASSES), st.frames
    truth = torch.arange(M).repeat_interleave(calib.shape[1])
    streams = calib.reshape(-1, frames, M)
    if st.fixed_temper is not None:
        temper = {"value": st.fixed_temper, "fitted": False}
    elif posterior.noise_model.sequences:  # the model integrates each sequence's look out: no temper to fit
        temper = {"value": 1.0, "fitted": False, "needed": False}
    else:
        fitted = hbni_pyro.fit_temper(posterior, streams, truth, settings.hbni.filter.mode)
        temper = {
            "value": fitted.temper,
            "fitted": True,
            "grid": fitted.grid.tolist(),
            "log_score": fitted.log_score.tolist(),
        }
    threshold = st.threshold
    stop: dict[str, Any] = {"value": threshold, "fitted": False}
    if st.hbni_stop == "calibrated":
        folds = st.stop_folds
        clock.say(f"choosing HBNI's stop on {folds} held-out folds of the calibration sequences")
        held_out = stop_folds(
            calib, settings.hbni, settings.seed, "fit", folds=folds, temper=temper["value"], progress=settings.progress
        )
        fitted_stop = hbni_pyro.fit_stop_threshold(held_out, None, None, threshold, frames)
        stop = {"fitted": True, "folds": folds, **fitted_stop._asdict(), "value": fitted_stop.stop}
        del stop["stop"]
    return Noise(posterior, temper, peer, stop)


def fit_peer(calib: torch.Tensor, settings: Mission, run_dir: Path) -> Peer:
    """The calibrated peer on the same labelled calibration outputs ``(C, S, F, C)`` HBNI gets: the per-frame map
    ``mission.calibration`` (saved as ``calibration``), then SSBF's evidence weight for correlated frames fitted on
    the calibration sequences as a frame-level HBNI model's temper is (:func:`hbni_pyro.fit_temper`)."""
    M, frames = len(CLASSES), settings.mission.frames
    labels = torch.arange(M).view(-1, 1, 1).expand(calib.shape[:3])
    calibration = hbni_pyro.fit_frame_calibration(calib, labels, settings.mission.calibration, class_names=CLASSES)
    save_artifact(run_dir, "calibration", calibration)
    truth = torch.arange(M).repeat_interleave(calib.shape[1])
    peer = hbni_pyro.make_filter("calibrated", calibration=calibration)
    fitted = hbni_pyro.fit_temper(peer, calib.reshape(-1, frames, M), truth)
    return Peer(calibration, fitted.temper, fitted.log_score.tolist())


def characterize_processes(
    noise: Noise, held: torch.Tensor, settings: Mission, clock: StageClock, run_dir: Path
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """Stage 4: each variant's macro-observation table on the held-out streams (saved as ``macro_<variant>``)."""
    clock.start("characterize", "4/6 characterising the macro-observation processes on held-out streams")
    M = len(CLASSES)
    streams = held.reshape(-1, settings.mission.frames, M)
    truth = torch.arange(M).repeat_interleave(held.shape[1])
    models = {}
    for name, process in build_processes(noise, settings).items():
        models[name] = hbni_pyro.tabulate(process, streams, truth)
        save_artifact(run_dir, f"macro_{name}", models[name])
    return models


def build_processes(noise: Noise, settings: Mission) -> dict[str, hbni_pyro.MacroObservationProcess]:
    """Each variant's macro-observation process: its filter, ``mission.threshold`` (HBNI: the stopping confidence
    that keeps that promise on the calibration sequences, with ``mission.hbni_stop=calibrated``) and the frame
    budget."""
    threshold = settings.mission.threshold
    stops = {"hbni": noise.stop["value"] if noise.stop else threshold}
    options: dict[str, dict[str, Any]] = {"hbni": {"mode": settings.hbni.filter.mode, "temper": noise.temper["value"]}}
    if noise.peer is not None:
        options["calibrated"] = {"calibration": noise.peer.calibration, "temper": noise.peer.temper}
    return {
        name: hbni_pyro.MacroObservationProcess(
            hbni_pyro.make_filter(name, noise.posterior, num_classes=len(CLASSES), **options.get(name, {})),
            threshold=stops.get(name, threshold),
            max_frames=settings.mission.frames,
        )
        for name in settings.variants
    }


def characterize_generative(
    noise: Noise, settings: Mission, clock: StageClock, run_dir: Path
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """Stage 4b: the generative planning model of the variants that need it (all of them when
    ``mission.planning_model=generative``, else HBNI when ``mission.compare_planning_models``): each
    process run on ``mission.generative_streams`` streams per class drawn from the posterior predictive
    of the fitted ``hbni.model`` (a posterior draw per stream; its frames i.i.d. given it under the
    frame-level models, sharing one look under ``sequence``, about which consecutive frames correlate as in the
    calibration sequences: :attr:`hbni_pyro.HBNIPosterior.frame_correlation`); saved as
    ``macro_<variant>_generative``."""
    st = settings.mission
    needed = (
        settings.variants
        if st.planning_model == "generative"
        else ([v for v in settings.variants if v == "hbni"] if st.compare_planning_models else [])
    )
    if needed:
        clock.start(
            "characterize_generative",
            f"4/6 characterising {', '.join(needed)} on streams simulated from the fitted HBNI model",
        )
    processes = build_processes(noise, settings)
    models = {}
    for name in needed:
        models[name] = hbni_pyro.characterize(
            processes[name], noise.posterior, st.generative_streams, stream_seed(settings.seed, "generative", name)
        )
        save_artifact(run_dir, f"macro_{name}_generative", models[name])
    return models


def planning_models(
    empirical: dict[str, hbni_pyro.MacroObservationModel],
    generative: dict[str, hbni_pyro.MacroObservationModel],
    settings: Mission,
) -> dict[str, hbni_pyro.MacroObservationModel]:
    """What each policy plans on: every variant on ``mission.planning_model``, and HBNI also on the other model
    (entry ``hbni_<other>``) when ``mission.compare_planning_models``."""
    st = settings.mission
    tables = {"empirical": empirical, "generative": generative}
    models = dict(tables[st.planning_model])
    other = closed_loop.other_model(st.planning_model)
    if st.compare_planning_models and "hbni" in tables[other]:
        models[f"hbni_{other}"] = tables[other]["hbni"]
    return models


def planners(settings: Mission) -> tuple[PlannerConfig, PlannerConfig | None]:
    """The planner's settings (``planner``) and those of the warm starts from the perfect-perception plan
    (``warm_planner``; ``None`` without ``warm_start``)."""
    return instantiate(settings.planner), instantiate(settings.warm_planner) if settings.warm_start else None


def plan(
    models: dict[str, hbni_pyro.MacroObservationModel],
    settings: Mission,
    clock: StageClock,
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
    clock.start("plan", "5/6 planning on the disaster-relief domain (no hand-written controller)")
    planner, warm = planners(settings)
    study, seed, reeval = settings.study, settings.seed, settings.study.reeval_rollouts
    results: dict[str, Any] = {}
    histories = {}
    start = None  # with warm_start: the perfect-perception plan every perception variant starts from

    def free() -> int:
        """The threads the bank's workers leave, asked at every rollout call: all of them once it is built."""
        return max(1, study.threads - (bank.workers if bank is not None and bank.building else 0))

    for name in ("perfect", *models):
        with threads(free):
            env = instantiate(settings.domain, perception=None if name == "perfect" else models[name])
            greedy = greedy_controller(env.num_agents)
            result, best, entry = run_planner(
                env,
                planner if start is None else warm,
                study.shared_controller,
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


def write_outputs(
    run_dir: Path,
    settings: Mission,
    clock: StageClock,
    outputs: Outputs,
    noise: Noise,
    models: dict[str, hbni_pyro.MacroObservationModel],
    results: dict[str, dict],
    histories: dict[str, dict],
    bank: BankBuild,
    reliability: plt.Figure | None,
) -> dict:
    """Figures, ``report.md``; returns the metrics."""
    planner, warm = planners(settings)
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
    st = settings.mission
    calib, held = outputs
    metrics = {
        "classes": CLASSES,
        "variants": results,
        "acceptance": mission_report.acceptance(results),
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
        "conditions": {"preset": "mission", "overrides": st.overrides},
        "hbni_temper": noise.temper,
        "hbni_stop": noise.stop,
        "calibrated_peer": None if noise.peer is None else noise.peer.summary(),
        "hbni_frame_correlation": noise.posterior.frame_correlation,
        "theta_summary": {k: v for k, v in noise.posterior.summary().items() if k.startswith("theta")},
        "planner": dataclasses.asdict(planner),
        "warm_planner": None if warm is None else dataclasses.asdict(warm),
        "wrong_penalty": settings.domain.wrong_penalty,
        "frame_period": settings.domain.frame_period,
        "sizes": {
            "train_snapshots_per_class": st.train_per_class,
            "calibration_frames": int(calib[..., 0].numel()),
            "held_out_streams": int(held.shape[0] * held.shape[1]),
            "generative_streams_per_class": st.generative_streams,
            "frames_per_stream": st.frames,
        },
        "cpu_seconds": _cpu_seconds(),
        "stage_seconds": clock.seconds(),
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
