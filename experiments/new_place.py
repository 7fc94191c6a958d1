"""A new place, few or no labels: HBNI adapted on the robot's own unlabelled streams against calibrating elsewhere.

The classifier and the labelled calibration come from the places the project already has (the mission's
training snapshots and its labelled mission-condition sequences: the *old place*). The mission then runs at a
*new place* whose imaging neither saw (``new_place.new.conditions``: dusk), where the robot has ``K`` labelled
sequences per class (``new_place.labelled``) and ``U`` unlabelled streams of objects in an unbalanced class mix
(``new_place.unlabelled``, ``new_place.mix``). :func:`run` reads as its stages:

1. :func:`perceive`: train the classifier as the mission does, and classify the old place's labelled sequences,
   the new place's labelled pool and unlabelled streams (cached by everything that produced them); start the
   bank of held-out new-place sequences for the closed loop (:class:`~experiments.steps.bank.BankBuild`).
2. :func:`fit_variants`: every filter fitted on exactly what it may use:
   - ``hbni_old``: HBNI fitted on the old place's labels, stopping where its labels kept the promise on held-out
     folds there (what the mission does, carried to the new place);
   - ``calibrated_K<k>``: the calibrated peer (Dirichlet calibration + SSBF with its evidence weight) on the ``k``
     labelled new-place sequences per class, or on the old place's labelled frames when ``k = 0``;
   - ``hbni_K<k>``: HBNI adapted from the old posterior on the ``k`` labelled and ``U`` unlabelled new-place
     sequences (:func:`hbni_pyro.adapt`), stopping at the confidence that keeps the promise on those streams,
     the unlabelled ones scored by its own posterior given each whole stream (:func:`hbni_pyro.fit_stop_unlabelled`).
3. :func:`plan_variants`: each variant's process tabulated on streams simulated from the noise model of the data it
   may use (the generative table, as the mission's: the old posterior for the old place's filters, the adapted one
   for HBNI, the old posterior adapted on the ``k`` labels alone for the peer), and its policy planned on it from
   the perfect-perception plan.
4. :func:`execute`: every policy run in closed loop, each "infer" MA answered by its variant's process on a held-out
   new-place sequence of the true class: the executed value with its rollout and stream standard errors, and the
   process on those streams (right, right when it emits, timeouts, frames).

With ``new_place.photos`` the same filters are compared on real photographs (:mod:`classifiers.photos`): the old
place is the noise-model study's ``"degraded"`` camera, the new one a darker camera with stronger casts and noise
(``new_place.photos.conditions``), each filter's process run on held-out new-place sequences (no mission to plan).

Writes ``metrics.json``, ``report.md``, ``new_place.png`` (and ``new_place_photos.png``), every posterior,
calibration, table and controller (``artifacts.json``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any, NamedTuple

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

import hbni_pyro
from classifiers import FrameClassifier, class_columns
from classifiers.data import Conditions, get_conditions
from classifiers.photos import PHOTOS, PhotoConditions, get_photo_conditions, photo_sequence, photo_snapshots
from decpomdp import JointController
from decpomdp.domains.disaster_relief import CLASSES
from decpomdp.search import PlannerConfig
from experiments import new_place_report
from experiments.artifacts import save_artifact
from experiments.common import save_figure
from experiments.report import write_report
from experiments.steps import closed_loop
from experiments.steps.bank import BankBuild, BankSpec, classifier_identity, code_identity
from experiments.steps.closed_loop import Bootstrap
from experiments.steps.noise import fit_labelled, stop_folds
from experiments.steps.perception import class_mix_outputs, sequence_outputs, train_classifier
from experiments.steps.planning import run_planner
from hbni_infra.cache import cached
from hbni_infra.streams import stream_seed
from hbni_infra.threads import threads


STOPS = tuple(round(0.5 + 0.01 * i, 2) for i in range(50)) + (0.995, 0.999)
"""Candidate stops of the adapted models' label-free stop: every hundredth, for a stop as low as the promise allows."""


class Place(NamedTuple):
    """What the robot has at the new place: ``labelled`` pool sizes ``K`` per class, ``unlabelled`` streams in the
    class ``mix``."""

    conditions: Conditions
    labelled: tuple[int, ...]
    unlabelled: int
    mix: tuple[float, ...]


class Settings(NamedTuple):
    """The study's validated settings, read once from the config (``experiments.schemas``)."""

    seed: int
    progress: bool
    threads: int
    classifier: DictConfig  # the classifier's _target_ block, instantiated by the perception step
    train_per_class: int
    augment: int
    frames: int
    threshold: float
    calibration: str
    old_conditions: Conditions
    old_sequences: int
    stop_folds: int
    new: Place
    shift_sd: float
    prevalence: float
    hbni: DictConfig  # model, hyperprior, fit settings and filter mode (the steps' fit_labelled reads it)
    generative_streams: int
    bank_sequences: int
    cache_dir: Path
    workers: int
    bootstrap: Bootstrap
    planner: PlannerConfig
    warm_planner: PlannerConfig
    domain: DictConfig
    reeval_rollouts: int
    shared_controller: bool
    photos: Photos | None


class Photos(NamedTuple):
    """``new_place.photos``: the photograph study's sizes and the new camera's degradation."""

    train_per_class: int
    augment: int
    old_sequences: int
    test_sequences: int
    conditions: PhotoConditions


class Data(NamedTuple):
    """Classifier outputs (float64, columns in class order): the old place's labelled sequences ``(C, S, F, C)``,
    the new place's labelled pool ``(C, K max, F, C)``, its unlabelled streams ``(U, F, C)`` and their classes
    (known only to the report)."""

    old: torch.Tensor
    labelled: torch.Tensor
    unlabelled: torch.Tensor
    unlabelled_truth: torch.Tensor


class Variant(NamedTuple):
    """A filter fitted on what it may use: its process, the posterior its table is simulated from, its family
    (``hbni_old``, ``calibrated``, ``hbni``), the labelled sequences per class ``K`` it used and how it stops."""

    process: hbni_pyro.MacroObservationProcess
    model: hbni_pyro.HBNIPosterior
    family: str
    K: int
    stop: dict[str, Any]


def run(cfg: DictConfig, run_dir: Path) -> dict:
    settings = read_settings(cfg)
    clf = train(settings, run_dir)
    bank = start_bank(clf, settings, run_dir)
    try:
        data = perceive(clf, settings)
        variants = fit_variants(data, settings, run_dir)
        tables = {name: generative_table(v, settings, name, run_dir) for name, v in variants.items()}
        results = plan_variants(tables, settings, run_dir, bank)
        banked = bank.result(settings.progress).double()
        execute(banked, variants, results, settings, run_dir)
    finally:
        bank.cancel()
    photos = photo_study(settings, run_dir) if settings.photos is not None else None
    return write_outputs(run_dir, settings, data, variants, results, bank, photos)


def read_settings(cfg: DictConfig) -> Settings:
    """The study's settings from its config (already checked against its schema, ``experiments.schemas``)."""
    st = cfg.new_place
    photos = st.photos
    return Settings(
        seed=int(cfg.seed),
        progress=bool(cfg.progress),
        threads=int(cfg.study.threads),
        classifier=cfg.classifier,
        train_per_class=int(st.train_per_class),
        augment=int(st.augment),
        frames=int(st.frames),
        threshold=float(st.threshold),
        calibration=str(st.calibration),
        old_conditions=get_conditions("mission", **OmegaConf.to_container(st.old.conditions)),
        old_sequences=int(st.old.sequences),
        stop_folds=int(st.old.stop_folds),
        new=Place(
            get_conditions("mission", **OmegaConf.to_container(st.new.conditions)),
            tuple(int(k) for k in st.labelled),
            int(st.unlabelled),
            tuple(float(w) for w in st.mix),
        ),
        shift_sd=float(st.shift_sd),
        prevalence=float(st.prevalence),
        hbni=cfg.hbni,
        generative_streams=int(st.generative_streams),
        bank_sequences=int(st.bank.sequences),
        cache_dir=Path(os.path.expanduser(str(st.cache_dir))),
        workers=int(st.bank.workers),
        bootstrap=Bootstrap(int(st.bootstrap.replicates), int(st.bootstrap.rollouts)),
        planner=instantiate(cfg.planner),
        warm_planner=instantiate(cfg.warm_planner),
        domain=cfg.domain,
        reeval_rollouts=int(cfg.study.reeval_rollouts),
        shared_controller=bool(cfg.study.shared_controller),
        photos=None
        if photos is None
        else Photos(
            int(photos.train_per_class),
            int(photos.augment),
            int(photos.old_sequences),
            int(photos.test_sequences),
            dataclasses.replace(get_photo_conditions("degraded"), **_tuples(photos.conditions)),
        ),
    )


def _tuples(block: DictConfig) -> dict[str, Any]:
    """A config block's values, lists as tuples (how the conditions' dataclasses hold ranges)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in OmegaConf.to_container(block).items()}


def say(settings: Settings, message: str) -> None:
    if settings.progress:
        tqdm.write(f"[new_place] {message}")


def train(settings: Settings, run_dir: Path) -> FrameClassifier:
    """The frame classifier as the mission trains it (same snapshots, same seed): saved as ``classifier``."""
    say(settings, "training the frame classifier on training-condition snapshots")
    clf = train_classifier(
        settings.classifier,
        CLASSES,
        settings.train_per_class,
        settings.augment,
        stream_seed(settings.seed, "train"),
        settings.progress,
        settings.threads,
    )
    save_artifact(run_dir, "classifier", clf)
    return clf


def start_bank(clf: FrameClassifier, settings: Settings, run_dir: Path) -> BankBuild:
    """The held-out new-place sequences of the closed loop: from the cache, or built by background workers."""
    spec = BankSpec(
        tuple(CLASSES),
        settings.new.conditions,
        stream_seed(settings.seed, "new place", "bank"),
        settings.bank_sequences,
        settings.frames,
    )
    bank = BankBuild(spec, clf, run_dir / "classifier.safetensors", settings.cache_dir, settings.workers)
    say(settings, f"held-out new-place bank: {'cached' if bank.cached else 'building'} ({bank.path})")
    return bank


def perceive(clf: FrameClassifier, settings: Settings) -> Data:
    """Classifier outputs of the old place's labelled sequences (the mission's calibration sequences: same
    conditions, same stream), the new place's labelled pool and its unlabelled streams; cached under the
    classifier, the code that draws frames, the conditions, the seed and the sizes."""
    new, seed = settings.new, settings.seed
    counts = class_counts(new.mix, new.unlabelled)
    key = {
        "kind": "experiments.new_place.outputs",
        "classifier": classifier_identity(clf),
        "code": code_identity(),
        "classes": list(CLASSES),
        "old": dataclasses.asdict(settings.old_conditions),
        "new": dataclasses.asdict(new.conditions),
        "seed": seed,
        "sizes": [settings.old_sequences, max(new.labelled), counts, settings.frames],
    }

    def compute() -> dict[str, torch.Tensor]:
        say(settings, "classifying the old place's labelled sequences and the new place's labelled and unlabelled")
        grid = lambda n, cond, stream, desc: sequence_outputs(  # noqa: E731
            clf, CLASSES, n, settings.frames, cond, stream, settings.progress, desc, settings.threads
        )[0]
        streams, truth = class_mix_outputs(
            clf,
            CLASSES,
            counts,
            settings.frames,
            new.conditions,
            stream_seed(seed, "new place", "unlabelled"),
            settings.progress,
            "new place, unlabelled",
            settings.threads,
        )
        return {
            "old": grid(settings.old_sequences, settings.old_conditions, stream_seed(seed, "calibration"), "old place"),
            "labelled": grid(
                max(new.labelled), new.conditions, stream_seed(seed, "new place", "labelled"), "new place, labelled"
            ),
            "unlabelled": streams,
            "unlabelled_truth": truth,
        }

    tensors, path, hit = cached(settings.cache_dir, "new_place_outputs", key, compute)
    if hit:
        say(settings, f"classifier outputs from the cache {path}")
    return Data(*(tensors[k].double() if k != "unlabelled_truth" else tensors[k] for k in Data._fields))


def class_counts(mix: tuple[float, ...], total: int) -> list[int]:
    """Sequences per class of ``total`` streams in the class ``mix`` (largest remainders; every class at least 1)."""
    raw = [w / sum(mix) * total for w in mix]
    counts = [max(1, math.floor(r)) for r in raw]
    for i in sorted(range(len(mix)), key=lambda i: raw[i] - math.floor(raw[i]), reverse=True):
        if sum(counts) >= total:
            break
        counts[i] += 1
    return counts


def fit_variants(data: Data, settings: Settings, run_dir: Path, classes: list[str] = CLASSES) -> dict[str, Variant]:
    """Every filter of the study, each fitted on exactly what it may use (the module docstring's list); ``classes``
    name the outputs' columns."""
    seed, M, F = settings.seed, len(classes), settings.frames
    say(settings, "fitting HBNI on the old place's labels and choosing its stop on held-out folds there")
    old = fit_labelled(data.old, settings.hbni, stream_seed(seed, "fit"), settings.progress, class_names=classes)
    save_artifact(run_dir, "posterior_old", old)
    folds = stop_folds(data.old, settings.hbni, seed, "fit", folds=settings.stop_folds, progress=settings.progress)
    old_stop = hbni_pyro.fit_stop_threshold(folds, None, None, settings.threshold, F)
    variants = {
        "hbni_old": Variant(
            process(hbni_pyro.make_filter("hbni", old, mode=settings.hbni.filter.mode), old_stop.stop, settings),
            old,
            "hbni_old",
            0,
            {"fitted_on": "old place, held-out folds", **old_stop._asdict()},
        )
    }
    for K in settings.new.labelled:
        say(settings, f"K = {K}: the calibrated peer, and HBNI adapted on {K} labelled + the unlabelled streams")
        labelled = data.labelled[:, :K]
        peer_data = data.old if K == 0 else labelled
        peer = fit_peer(peer_data, settings, run_dir, f"calibration_K{K}", classes)
        peer_model = old if K == 0 else adapt(old, labelled, None, settings, ("peer", K))
        variants[f"calibrated_K{K}"] = Variant(
            process(peer, settings.threshold, settings), peer_model, "calibrated", K, {"value": settings.threshold}
        )
        streams = torch.cat([labelled.reshape(-1, F, M), data.unlabelled])
        labels = torch.cat([torch.arange(M).repeat_interleave(K), torch.full((len(data.unlabelled),), -1)])
        adapted = adapt(old, streams, labels, settings, ("adapt", K))
        save_artifact(run_dir, f"posterior_K{K}", adapted)
        hbni = hbni_pyro.make_filter("hbni", adapted, mode=settings.hbni.filter.mode)
        stop = hbni_pyro.fit_stop_unlabelled(hbni, streams, settings.threshold, F, grid=STOPS, labels=labels)
        variants[f"hbni_K{K}"] = Variant(
            process(hbni, stop.stop, settings),
            adapted,
            "hbni",
            K,
            {"fitted_on": f"{K} labelled + {len(data.unlabelled)} unlabelled new-place streams", **stop._asdict()},
        )
    return variants


def process(filter: hbni_pyro.StreamingFilter, stop: float, settings: Settings) -> hbni_pyro.MacroObservationProcess:
    return hbni_pyro.MacroObservationProcess(filter, threshold=stop, max_frames=settings.frames)


def adapt(
    old: hbni_pyro.HBNIPosterior, streams: torch.Tensor, labels: torch.Tensor | None, settings: Settings, stream: tuple
) -> hbni_pyro.HBNIPosterior:
    """``old`` adapted to the new place on ``streams``: ``(B, F, M)`` with ``labels (B,)`` (-1 unknown), or a grid
    ``(C, K, F, C)`` of labelled sequences with ``labels=None``."""
    if labels is None:
        C, K = streams.shape[:2]
        labels = torch.arange(C).repeat_interleave(K)
        streams = streams.reshape(C * K, *streams.shape[2:])
    B, F, M = streams.shape
    fit = OmegaConf.to_container(settings.hbni.fit)
    fit.pop("method")
    return hbni_pyro.adapt(
        old,
        streams.reshape(-1, M),
        labels.repeat_interleave(F),
        sequence_ids=torch.arange(B).repeat_interleave(F),
        shift_sd=settings.shift_sd,
        prevalence=settings.prevalence,
        seed=stream_seed(settings.seed, *stream),
        progress=settings.progress,
        hyperprior=instantiate(settings.hbni.hyperprior),
        **fit,
    )


def fit_peer(
    outputs: torch.Tensor, settings: Settings, run_dir: Path, name: str, classes: list[str]
) -> hbni_pyro.StreamingFilter:
    """The calibrated peer on labelled sequences ``(C, S, F, C)`` of ``classes``: the per-frame map (saved as
    ``name``), then SSBF's evidence weight fitted on the same sequences (as the mission's)."""
    C, S = outputs.shape[:2]
    labels = torch.arange(C).view(-1, 1, 1).expand(outputs.shape[:3])
    calibration = hbni_pyro.fit_frame_calibration(outputs, labels, settings.calibration, class_names=classes)
    save_artifact(run_dir, name, calibration)
    peer = hbni_pyro.make_filter("calibrated", calibration=calibration)
    truth = torch.arange(C).repeat_interleave(S)
    return peer.tempered(hbni_pyro.fit_temper(peer, outputs.reshape(C * S, *outputs.shape[2:]), truth).temper)


def generative_table(variant: Variant, settings: Settings, name: str, run_dir: Path) -> hbni_pyro.MacroObservationModel:
    """The variant's process run on streams simulated from its noise model (saved as ``macro_<name>``)."""
    table = hbni_pyro.characterize(
        variant.process, variant.model, settings.generative_streams, stream_seed(settings.seed, "generative", name)
    )
    save_artifact(run_dir, f"macro_{name}", table)
    return table


def plan_variants(
    tables: dict[str, hbni_pyro.MacroObservationModel], settings: Settings, run_dir: Path, bank: BankBuild
) -> dict[str, dict[str, Any]]:
    """Perfect perception planned from scratch, then each variant from that plan on its own table (saved as
    ``controller_<name>``), each re-evaluated on fresh rollouts; rollouts on the threads the bank's workers leave."""
    say(settings, "planning: perfect perception from scratch, then every variant from that plan")
    results: dict[str, dict[str, Any]] = {}
    start = None

    def free() -> int:
        return max(1, settings.threads - (bank.workers if bank.building else 0))

    for name in tqdm(["perfect", *tables], desc="planning", disable=not settings.progress):
        with threads(free):
            env = instantiate(settings.domain, perception=None if name == "perfect" else tables[name])
            result, best, entry = run_planner(
                env,
                settings.planner if start is None else settings.warm_planner,
                settings.shared_controller,
                stream_seed(settings.seed, "plan", name),
                False,
                settings.reeval_rollouts,
                init=start,
            )
        start = result.best if start is None else start
        save_artifact(run_dir, f"controller_{name}", best)
        if name != "perfect":
            entry["macro_accuracy"] = tables[name].accuracy.tolist()
            entry["macro_mean_frames"] = tables[name].mean_frames.tolist()
        results[name] = entry
    return results


def execute(
    bank: torch.Tensor,
    variants: dict[str, Variant],
    results: dict[str, dict[str, Any]],
    settings: Settings,
    run_dir: Path,
) -> None:
    """Every policy in closed loop on the held-out bank ``(C, S, F, C)``: adds ``executed`` (value, rollout and stream
    standard errors) and ``held_out_process`` to each variant's entry."""
    say(settings, "executing every policy in closed loop on the held-out new-place bank")
    C, S = bank.shape[:2]
    for name in tqdm(list(results), desc="closed loop", disable=not settings.progress):
        controller = JointController.load(run_dir / f"controller_{name}.safetensors")
        seed = stream_seed(settings.seed, "execute", name)
        if name == "perfect":
            executed = closed_loop.execute(controller, None, settings.domain, settings.reeval_rollouts, seed)
            results[name]["executed"] = closed_loop.summarise(results[name], executed, None)
            continue
        with threads(settings.threads):
            replay = hbni_pyro.StreamReplay(variants[name].process, *closed_loop.as_streams(bank))
            executed = closed_loop.execute(controller, replay, settings.domain, settings.reeval_rollouts, seed)
            streams_se = closed_loop.stream_stderr(
                controller,
                lambda idx: closed_loop.resampled(replay, C, S, idx),
                S,
                S,
                settings.domain,
                settings.bootstrap,
                stream_seed(settings.seed, "bootstrap", name),
            )
        entry = closed_loop.summarise(results[name], executed, replay, 0.0, streams_se)
        entry["total_stderr"] = math.hypot(entry["stderr"], streams_se)
        results[name]["executed"] = entry
        results[name]["held_out_process"] = closed_loop.held_out_checks(replay, settings.threshold)


def photo_study(settings: Settings, run_dir: Path) -> dict[str, Any]:
    """The same filters on real photographs: classifier on training-preset snapshots, the old place the
    ``"degraded"`` camera, the new one ``new_place.photos.conditions``; each filter's process on held-out new-place
    sequences (right, right when it emits, timeouts, frames)."""
    p, seed, F, M = settings.photos, settings.seed, settings.frames, len(PHOTOS)
    new = settings.new
    counts = class_counts(new.mix, new.unlabelled)
    clf: FrameClassifier = instantiate(settings.classifier)
    key = {
        "kind": "experiments.new_place.photos",
        "classifier": OmegaConf.to_container(settings.classifier, resolve=True),
        "code": code_identity(),
        "seed": seed,
        "new": p.conditions.to_dict(),
        "sizes": [p.train_per_class, p.augment, p.old_sequences, p.test_sequences, max(new.labelled), counts, F],
    }

    def compute() -> dict[str, torch.Tensor]:
        say(settings, "photographs: training the classifier, classifying old- and new-camera sequences")
        images = [im for name in PHOTOS for im in photo_snapshots(name, p.train_per_class, "training", seed)]
        clf.fit(images, [n for n in PHOTOS for _ in range(p.train_per_class)], augment=p.augment, progress=False)
        order = class_columns(clf, list(PHOTOS))

        def grid(counts: list[int], conditions: Any, part: str) -> list[torch.Tensor]:
            """Outputs ``(counts[c], F, M)`` of each photograph ``c``'s sequences under ``conditions``."""
            s = stream_seed(seed, "photos", part)
            return [
                torch.stack(
                    [clf.predict_proba(photo_sequence(n, F, conditions, s, index=i))[:, order] for i in range(k)]
                )
                for n, k in tqdm(list(zip(PHOTOS, counts)), desc=f"photos, {part}", disable=not settings.progress)
            ]

        return {
            "old": torch.stack(grid([p.old_sequences] * M, "degraded", "calibration")),  # the noise-model study's
            "labelled": torch.stack(grid([max(new.labelled)] * M, p.conditions, "new labelled")),
            "unlabelled": torch.cat(grid(counts, p.conditions, "new unlabelled")),
            "unlabelled_truth": torch.arange(M).repeat_interleave(torch.tensor(counts)),
            "test": torch.stack(grid([p.test_sequences] * M, p.conditions, "new held-out")),
        }

    tensors, path, hit = cached(settings.cache_dir, "new_place_photos", key, compute)
    if hit:
        say(settings, f"photographs: classifier outputs from the cache {path}")
    data = Data(*(tensors[k].double() if k != "unlabelled_truth" else tensors[k] for k in Data._fields))
    photo_settings = settings._replace(seed=stream_seed(seed, "photos"), old_sequences=p.old_sequences, photos=None)
    (run_dir / "photos").mkdir(exist_ok=True)
    variants = fit_variants(data, photo_settings, run_dir / "photos", list(PHOTOS))
    test = tensors["test"].double()
    streams, truth = closed_loop.as_streams(test)
    return {
        "classes": list(PHOTOS),
        "conditions": p.conditions.to_dict(),
        "frame_accuracy": {
            "old": _frame_accuracy(data.old),
            "new": _frame_accuracy(test),
        },
        "variants": {
            name: {
                "family": v.family,
                "K": v.K,
                "stop": v.process.threshold,
                "held_out_process": closed_loop.held_out_checks(
                    hbni_pyro.StreamReplay(v.process, streams, truth), settings.threshold
                ),
            }
            for name, v in variants.items()
        },
    }


def _frame_accuracy(outputs: torch.Tensor) -> float:
    """Share of frames ``(C, S, F, C)`` whose top class is the true one."""
    truth = torch.arange(outputs.shape[0]).view(-1, 1, 1)
    return float((outputs.argmax(-1) == truth).double().mean())


def write_outputs(
    run_dir: Path,
    settings: Settings,
    data: Data,
    variants: dict[str, Variant],
    results: dict[str, dict[str, Any]],
    bank: BankBuild,
    photos: dict[str, Any] | None,
) -> dict[str, Any]:
    """``metrics.json`` (returned), ``report.md`` and the figures."""
    for name, v in variants.items():
        results[name].update(family=v.family, K=v.K, stop=v.stop)
    adapted = {name: v.model for name, v in variants.items() if v.family == "hbni"}
    truth = data.unlabelled_truth
    M = len(CLASSES)
    metrics = {
        "classes": CLASSES,
        "labelled": list(settings.new.labelled),
        "unlabelled": {
            "streams": len(truth),
            "mix": torch.bincount(truth, minlength=M).tolist(),
            "fitted_mix": {name: p.info["sites"]["prevalence"]["mean"] for name, p in adapted.items()},
            "classes_recovered": {
                name: float(
                    (p.label_probs.reshape(-1, settings.frames, M)[-len(truth) :, 0].argmax(-1) == truth)
                    .double()
                    .mean()
                )
                for name, p in adapted.items()
            },
        },
        "frame_accuracy": {"old": _frame_accuracy(data.old), "new": _frame_accuracy(data.labelled)},
        "conditions": {
            "old": dataclasses.asdict(settings.old_conditions),
            "new": dataclasses.asdict(settings.new.conditions),
        },
        "variants": results,
        "acceptance": new_place_report.acceptance(results, settings.new.labelled, settings.threshold),
        "bank": {"path": str(bank.path), "cached": bank.cached, "sequences_per_class": settings.bank_sequences},
    }
    if photos is not None:
        metrics["photos"] = photos
    figures = {"new_place.png": new_place_report.figure(results, settings.new.labelled, "the mission at dusk")}
    if photos is not None:
        figures["new_place_photos.png"] = new_place_report.process_figure(
            photos["variants"], settings.new.labelled, "photographs, a darker camera"
        )
    for file, fig in figures.items():
        save_figure(fig, run_dir / file)
    write_report(run_dir / "report.md", new_place_report.report(metrics, list(figures)))
    return metrics
