"""A new place, few or no labels: HBNI adapted on the robot's own unlabelled streams against calibrating elsewhere.

The classifier and the labelled calibration come from the places the project already has (the mission's
training snapshots and its labelled mission-condition sequences: the *old place*). The mission then runs at a
*new place* whose imaging neither saw (``new_place.new.conditions``: dusk), where the robot has ``K`` labelled
sequences per class (``new_place.labelled``) and ``U`` unlabelled streams of objects in an unbalanced class mix
(``new_place.unlabelled``, ``new_place.mix``). :func:`run` reads as its stages:

1. :func:`train` and :func:`perceive`: train the classifier as the mission does, and classify the old place's
   labelled sequences, the new place's labelled pool and unlabelled streams (cached by everything that produced
   them); :func:`start_bank`: the bank of held-out new-place sequences for the closed loop.
2. :func:`~experiments.steps.place_variants.fit_variants`: HBNI from the old place, the calibrated peer and HBNI
   adapted, each fitted on exactly what it may use, for every ``K``.
3. :func:`generative_table` and :func:`plan_variants`: each variant's process tabulated on streams simulated from
   the noise model of the data it may use (as the mission's generative table: the old posterior for the old place's
   filters, the adapted one for HBNI, the old posterior adapted on the ``k`` labels alone for the peer), and its
   policy planned on it from the perfect-perception plan.
4. :func:`execute`: every policy run in closed loop, each "infer" MA answered by its variant's process on a held-out
   new-place sequence of the true class: the executed value with its rollout and stream standard errors, and the
   process on those streams (right, right when it emits, timeouts, frames).

With ``new_place.photos`` the same filters are compared on real photographs (:mod:`experiments.steps.place_photos`).
Every stage reads the typed :class:`~experiments.schemas.new_place_study.NewPlace` settings the entry point built.

Writes ``metrics.json``, ``report.md``, ``new_place.png`` (and ``new_place_photos.png``), every posterior,
calibration, table and controller (``artifacts.json``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import torch
from hydra.utils import instantiate
from tqdm.auto import tqdm

import hbni_pyro
from classifiers import FrameClassifier
from decpomdp import JointController
from decpomdp.domains.disaster_relief import CLASSES
from experiments.reports import new_place_report
from experiments.runs.artifacts import save_artifact
from experiments.runs.outputs import save_figure, write_report
from experiments.schemas.new_place_study import NewPlace
from experiments.steps import closed_loop
from experiments.steps.bank import BankBuild, BankSpec, classifier_identity, code_identity
from experiments.steps.classification import class_mix_outputs, sequence_outputs, train_study_classifier
from experiments.steps.place_photos import photo_study
from experiments.steps.place_variants import PlaceData, Variant, fit_variants, frame_accuracy, say
from experiments.steps.planning import run_planner
from hbni_infra.cache import cached
from hbni_infra.streams import stream_seed
from hbni_infra.threads import threads


def run(settings: NewPlace, run_dir: Path) -> dict:
    clf = train(settings, run_dir)
    bank = start_bank(clf, settings, run_dir)
    try:
        data = perceive(clf, settings)
        variants = fit_variants(data, settings, settings.seed, run_dir, list(CLASSES))
        tables = {name: generative_table(v, settings, name, run_dir) for name, v in variants.items()}
        results = plan_variants(tables, settings, run_dir, bank)
        banked = bank.result(settings.progress).double()
        execute(banked, variants, results, settings, run_dir)
    finally:
        bank.cancel()
    photos = photo_study(settings, run_dir) if settings.new_place.photos is not None else None
    return write_outputs(run_dir, settings, data, variants, results, bank, photos)


def train(settings: NewPlace, run_dir: Path) -> FrameClassifier:
    """The frame classifier as the mission trains it (same snapshots, same seed): saved as ``classifier``."""
    say(settings, "training the frame classifier on training-condition snapshots")
    return train_study_classifier(settings, settings.new_place, list(CLASSES), run_dir)


def start_bank(clf: FrameClassifier, settings: NewPlace, run_dir: Path) -> BankBuild:
    """The held-out new-place sequences of the closed loop: from the cache, or built by background workers."""
    st = settings.new_place
    spec = BankSpec(
        tuple(CLASSES), st.new.imaging, stream_seed(settings.seed, "new place", "bank"), st.bank.sequences, st.frames
    )
    bank = BankBuild(spec, clf, run_dir / "classifier.safetensors", st.cache_path, st.bank.workers)
    say(settings, f"held-out new-place bank: {'cached' if bank.cached else 'building'} ({bank.path})")
    return bank


def perceive(clf: FrameClassifier, settings: NewPlace) -> PlaceData:
    """Classifier outputs of the old place's labelled sequences (the mission's calibration sequences: same
    conditions, same stream), the new place's labelled pool and its unlabelled streams; cached under the
    classifier, the code that draws frames, the conditions, the seed and the sizes."""
    st, seed = settings.new_place, settings.seed
    counts = st.unlabelled_counts()
    old, new = st.old.imaging, st.new.imaging
    key = {
        "kind": "experiments.new_place.outputs",
        "classifier": classifier_identity(clf),
        "code": code_identity(),
        "classes": list(CLASSES),
        "old": dataclasses.asdict(old),
        "new": dataclasses.asdict(new),
        "seed": seed,
        "sizes": [st.old.sequences, max(st.labelled), counts, st.frames],
    }

    def grid(per_class: int, conditions: Any, stream: int, desc: str) -> torch.Tensor:
        return sequence_outputs(
            clf, CLASSES, per_class, st.frames, conditions, stream, settings.progress, desc, settings.study.threads
        )[0]

    def compute() -> dict[str, torch.Tensor]:
        say(settings, "classifying the old place's labelled sequences and the new place's labelled and unlabelled")
        streams, truth = class_mix_outputs(
            clf,
            CLASSES,
            counts,
            st.frames,
            new,
            stream_seed(seed, "new place", "unlabelled"),
            settings.progress,
            "new place, unlabelled",
            settings.study.threads,
        )
        return {
            "old": grid(st.old.sequences, old, stream_seed(seed, "calibration"), "old place"),
            "labelled": grid(max(st.labelled), new, stream_seed(seed, "new place", "labelled"), "new place, labelled"),
            "unlabelled": streams,
            "unlabelled_truth": truth,
        }

    tensors, path, hit = cached(st.cache_path, "new_place_outputs", key, compute)
    if hit:
        say(settings, f"classifier outputs from the cache {path}")
    return PlaceData.of(tensors)


def generative_table(variant: Variant, settings: NewPlace, name: str, run_dir: Path) -> hbni_pyro.MacroObservationModel:
    """The variant's process run on streams simulated from its noise model (saved as ``macro_<name>``)."""
    table = hbni_pyro.characterize(
        variant.process,
        variant.model,
        settings.new_place.generative_streams,
        stream_seed(settings.seed, "generative", name),
    )
    save_artifact(run_dir, f"macro_{name}", table)
    return table


def plan_variants(
    tables: dict[str, hbni_pyro.MacroObservationModel], settings: NewPlace, run_dir: Path, bank: BankBuild
) -> dict[str, dict[str, Any]]:
    """Perfect perception planned from scratch, then each variant from that plan on its own table (saved as
    ``controller_<name>``), each re-evaluated on fresh rollouts; rollouts on the threads the bank's workers leave."""
    say(settings, "planning: perfect perception from scratch, then every variant from that plan")
    study = settings.study
    planner, warm = instantiate(settings.planner), instantiate(settings.warm_planner)
    results: dict[str, dict[str, Any]] = {}
    start = None

    def free() -> int:
        return max(1, study.threads - (bank.workers if bank.building else 0))

    for name in tqdm(["perfect", *tables], desc="planning", disable=not settings.progress):
        with threads(free):
            env = instantiate(settings.domain, perception=None if name == "perfect" else tables[name])
            result, best, entry = run_planner(
                env,
                planner if start is None else warm,
                study.shared_controller,
                stream_seed(settings.seed, "plan", name),
                False,
                study.reeval_rollouts,
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
    settings: NewPlace,
    run_dir: Path,
) -> None:
    """Every policy in closed loop on the held-out bank ``(C, S, F, C)``: adds ``executed`` (value, rollout and stream
    standard errors) and ``held_out_process`` to each variant's entry."""
    say(settings, "executing every policy in closed loop on the held-out new-place bank")
    C, S = bank.shape[:2]
    rollouts, st = settings.study.reeval_rollouts, settings.new_place
    for name in tqdm(list(results), desc="closed loop", disable=not settings.progress):
        controller = JointController.load(run_dir / f"controller_{name}.safetensors")
        seed = stream_seed(settings.seed, "execute", name)
        if name == "perfect":
            executed = closed_loop.execute(controller, None, settings.domain, rollouts, seed)
            results[name]["executed"] = closed_loop.summarise(results[name], executed, None)
            continue
        with threads(settings.study.threads):
            replay = hbni_pyro.StreamReplay(variants[name].process, *closed_loop.as_streams(bank))
            executed = closed_loop.execute(controller, replay, settings.domain, rollouts, seed)
            streams_se = closed_loop.stream_stderr(
                controller,
                lambda idx: closed_loop.resampled(replay, C, S, idx),
                S,
                S,
                settings.domain,
                st.bootstrap,
                stream_seed(settings.seed, "bootstrap", name),
            )
        entry = closed_loop.summarise(results[name], executed, replay, 0.0, streams_se)
        entry["total_stderr"] = math.hypot(entry["stderr"], streams_se)
        results[name]["executed"] = entry
        results[name]["held_out_process"] = closed_loop.held_out_summary(replay, st.threshold)


def write_outputs(
    run_dir: Path,
    settings: NewPlace,
    data: PlaceData,
    variants: dict[str, Variant],
    results: dict[str, dict[str, Any]],
    bank: BankBuild,
    photos: dict[str, Any] | None,
) -> dict[str, Any]:
    """``metrics.json`` (returned), ``report.md`` and the figures."""
    st = settings.new_place
    for name, v in variants.items():
        results[name].update(family=v.family, K=v.K, stop=v.stop)
    adapted = {name: v.model for name, v in variants.items() if v.family == "hbni"}
    truth, M = data.unlabelled_truth, len(CLASSES)
    metrics = {
        "classes": CLASSES,
        "labelled": list(st.labelled),
        "unlabelled": {
            "streams": len(truth),
            "mix": torch.bincount(truth, minlength=M).tolist(),
            "fitted_mix": {name: p.info["sites"]["prevalence"]["mean"] for name, p in adapted.items()},
            "classes_recovered": {
                name: float(
                    (p.label_probs.reshape(-1, st.frames, M)[-len(truth) :, 0].argmax(-1) == truth).double().mean()
                )
                for name, p in adapted.items()
            },
        },
        "frame_accuracy": {"old": frame_accuracy(data.old), "new": frame_accuracy(data.labelled)},
        "conditions": {"old": dataclasses.asdict(st.old.imaging), "new": dataclasses.asdict(st.new.imaging)},
        "variants": results,
        "acceptance": new_place_report.acceptance(results, st.labelled, st.threshold),
        "bank": {"path": str(bank.path), "cached": bank.cached, "sequences_per_class": st.bank.sequences},
    }
    if photos is not None:
        metrics["photos"] = photos
    figures = {"new_place.png": new_place_report.figure(results, st.labelled, "the mission at dusk")}
    if photos is not None:
        figures["new_place_photos.png"] = new_place_report.process_figure(
            photos["variants"], st.labelled, "photographs, a darker camera"
        )
    for file, fig in figures.items():
        save_figure(fig, run_dir / file)
    write_report(run_dir / "report.md", new_place_report.report(metrics, list(figures)))
    return metrics
