"""Noise models compared: the paper's, confusion-aware and sequence-aware HBNI against SSBF and max-of-mean.

:func:`run` reads as its stages:

1. :func:`toy_study`: the paper's toy (true theta, unlabelled training sets, i.i.d. trial
   streams): classification error against the number of outputs for every model, and the
   smallest N with error at most ``study.toy.target``.
2. :mod:`experiments.steps.condition_outputs`: render the disaster-relief objects, train the frame classifier
   and classify labelled calibration and held-out sequences under each imaging condition
   (``study.conditions``: the default mission conditions and the in-flight preset), and from
   a user's image folder (``study.images``); the same for real photographs under a moving, dim, blurred and
   occluded camera (``study.photos``, :mod:`classifiers.photos`). Outputs are cached on disk by their inputs.
3. :func:`evaluate_condition`, per condition: fit every model on the calibration sequences (the
   paper's and the confusion-aware model also with the temper fitted on them), then on the
   held-out sequences score each filter: held-out log score (the mean log posterior of the
   true class over every prefix), argmax accuracy after all frames, reliability and expected
   calibration error, and the macro-observation process at each threshold (accuracy of the
   labels it emits, timeout rate, mean frames).
4. :func:`acceptance`: the best model (by held-out log score) against the issue's floors; on the
   photographs also the default model (``sequence``) against its target, and :func:`honesty`:
   for every filter and threshold ``t``, whether its emitted labels are right at least ``t - 0.03``.

Writes ``metrics.json``, ``report.md`` (a table per condition), ``toy_error.png``,
``accuracy_vs_frames.png``, ``reliability.png`` and every fitted posterior (``artifacts.json``).
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
from classifiers.photos import PHOTOS
from decpomdp.domains.disaster_relief import CLASSES
from experiments.reports import noise_models_report as report
from experiments.runs.artifacts import save_artifact
from experiments.runs.clock import StageClock
from experiments.runs.outputs import save_figure, write_report
from experiments.schemas.noise_studies import NoiseModels
from experiments.steps.condition_outputs import folder_outputs, mission_outputs, photo_outputs
from experiments.steps.noise import fit_labelled, stop_folds
from hbni_pyro import binomial_stderr, noise_model, sample_outputs, stream_reliability, threshold_checks
from hbni_pyro.validation import DTYPE
from hbni_infra.streams import stream_seed, torch_stream

BASELINES = ("ssbf", "max_of_mean")
DEFAULT_MODEL = "sequence"
"""The default noise model wherever real frames are filtered; its row ``sequence_stopped`` stops as early as its
promise allows (:func:`hbni_pyro.fit_stop_threshold` on calibration sequences held out of the fit)."""


def run(settings: NoiseModels, run_dir: Path) -> dict:
    clock = StageClock("noise_models", settings.progress)
    toy = toy_study(settings, run_dir)
    data = mission_outputs(settings, clock, run_dir)
    if settings.study.images:
        data["images"] = folder_outputs(settings, clock)
    if settings.study.photos:
        data["photos"] = photo_outputs(settings, clock, run_dir)
    conditions = {
        name: evaluate_condition(name, calib, held, settings, clock, run_dir) for name, (calib, held) in data.items()
    }
    metrics = {
        "toy": toy,
        "conditions": conditions,
        "acceptance": acceptance(toy, conditions, settings.study.models),
        "honesty": {name: honesty(cond) for name, cond in conditions.items()},
        "settings": dataclasses.asdict(settings.study),
    }
    figures = {
        "toy_error.png": report.toy_figure(toy),
        "accuracy_vs_frames.png": report.curve_figure(conditions),
        "reliability.png": report.reliability_figure(conditions),
    }
    for file, fig in figures.items():
        save_figure(fig, run_dir / file)
    write_report(run_dir / "report.md", report.markdown(metrics, list(figures)))
    clock.say(f"wrote {run_dir / 'report.md'}, metrics.json and the figures")
    return metrics


# -- 1. the paper's toy ---------------------------------------------------------------------------


def toy_study(settings: NoiseModels, run_dir: Path) -> dict[str, Any]:
    """Error against N on the paper's toy for every model and baseline (common random trials).

    Each of ``num_training_sets`` unlabelled training sets (``training_size`` outputs, balanced)
    is fitted by every model at once (:func:`hbni_pyro.fit_many`) and filters its own block of
    trials. The sequence model is told which outputs came from one object: each class's outputs
    of a training set are one sequence (the classes themselves stay unknown).
    """
    t, seed, hbni = settings.study.toy, settings.seed, settings.hbni
    theta = torch.tensor(t.theta, dtype=DTYPE)
    M, T, trials, sets, size = len(theta), t.max_len, t.num_trials, t.num_training_sets, t.training_size
    g = torch_stream(seed, "toy")
    truth = torch.randint(M, (trials,), generator=g)
    obs = sample_outputs(theta, truth.unsqueeze(1).expand(trials, T), g)
    classes = torch.arange(M).repeat_interleave(size // M)
    train = sample_outputs(theta, classes.expand(sets, -1), g)
    per_set = trials // sets
    wrong: dict[str, torch.Tensor] = {
        name: (hbni_pyro.decide(hbni_pyro.make_filter(name, num_classes=M).run(obs)) != truth[:, None]).sum(0)
        for name in ("ssbf", "max_of_mean")
    }
    for k, model in enumerate(settings.study.models):
        posts = hbni_pyro.fit_many(
            train,
            model=model,
            sequence_ids=classes,
            **hbni.fit.sizes(),
            seed=stream_seed(seed, "fit", model, k),
            progress=False,
            hyperprior=instantiate(hbni.hyperprior),
        )
        save_artifact(run_dir, f"toy_posterior_{model}", posts[0])
        counts = torch.zeros(T, dtype=torch.long)
        for d, post in enumerate(posts):
            rows = slice(d * per_set, (d + 1) * per_set)
            probs = hbni_pyro.HBNIFilter(post, hbni.filter.mode, num_draws=t.filter_draws).run(obs[rows])
            counts += (hbni_pyro.decide(probs) != truth[rows, None]).sum(0)
        wrong[model] = counts
    error = {k: v.to(DTYPE) / trials for k, v in wrong.items()}
    target = t.target
    crossing = {k: _first_at_most(e, target) for k, e in error.items()}
    return {
        "error": error,
        "crossing_n": crossing,
        "target": target,
        "trials": trials,
        "training_size": size,
        "training_sets": sets,
        "true_theta": theta,
    }


def _first_at_most(error: torch.Tensor, target: float) -> int | None:
    hit = (error <= target).nonzero()
    return int(hit[0]) + 1 if hit.numel() else None


# -- 2. classifier outputs ------------------------------------------------------------------------


# -- 3. per condition -----------------------------------------------------------------------------


def evaluate_condition(
    name: str, calib: torch.Tensor, held: torch.Tensor, settings: NoiseModels, clock: StageClock, run_dir: Path
) -> dict[str, Any]:
    """Fit every model on the calibration sequences and score every filter on the held-out ones."""
    study = settings.study
    clock.say(f"{name}: fitting {', '.join(study.models)} on {calib.shape[1]} calibration sequences per class")
    C, _, F, M = calib.shape
    filters = fitted_filters(name, calib, settings, run_dir)
    streams, truth = held.reshape(-1, F, M), torch.arange(C).repeat_interleave(held.shape[1])
    stops: dict[str, dict[float, float]] = {}
    if DEFAULT_MODEL in filters:  # the default: the sequence model stopping as early as its promise allows
        filters[f"{DEFAULT_MODEL}_stopped"] = filters[DEFAULT_MODEL]
        stops[f"{DEFAULT_MODEL}_stopped"] = held_out_stops(calib, settings)
    rows = {}
    for fname, f in tqdm(filters.items(), desc=f"{name} filters", disable=not settings.progress):
        rows[fname] = score_filter(f, streams, truth, study.thresholds, study.curve_thresholds, stops.get(fname))
    frame_acc = float((held.argmax(-1) == torch.arange(C).view(-1, 1, 1)).to(DTYPE).mean())
    return {
        "filters": rows,
        "temper": {k: f.temper for k, f in filters.items() if k.endswith("_tempered") or k.startswith("calibrated")},
        "stops": {k: {f"{t:g}": stop for t, stop in v.items()} for k, v in stops.items()},
        "sizes": {
            "calibration_sequences_per_class": calib.shape[1],
            "held_out_sequences": int(truth.numel()),
            "frames": F,
        },
        "frame_accuracy": frame_acc,
    }


def held_out_stops(calib: torch.Tensor, settings: NoiseModels) -> dict[float, float]:
    """The default model's stopping confidence per threshold, chosen on calibration sequences held out of its fit
    (:func:`hbni_pyro.cross_fit`: each fold's labels come from a model fitted on the other folds)."""
    folds = stop_folds(calib, settings.hbni, settings.seed, model=DEFAULT_MODEL)
    return {t: hbni_pyro.fit_stop_threshold(folds, None, None, t).stop for t in settings.study.thresholds}


def fitted_filters(name: str, calib: torch.Tensor, settings: NoiseModels, run_dir: Path) -> dict[str, Any]:
    """Every model's filter (and the tempered frame-level ones), then the baselines."""
    C, _, F, M = calib.shape
    calib_streams, calib_truth = calib.reshape(-1, F, M), torch.arange(C).repeat_interleave(calib.shape[1])
    mode = settings.hbni.filter.mode
    filters: dict[str, Any] = {}
    for model in settings.study.models:
        post = fit_labelled(calib, settings.hbni, settings.seed, False, model=model, class_names=_class_names(name))
        save_artifact(run_dir, f"posterior_{name}_{model}", post)
        filters[model] = hbni_pyro.make_filter("hbni", post, mode=mode)
        if not noise_model(
            model
        ).sequences:  # frame-level models also run with the temper fitted on the calibration sequences
            tau = hbni_pyro.fit_temper(post, calib_streams, calib_truth, mode).temper
            filters[f"{model}_tempered"] = hbni_pyro.make_filter("hbni", post, mode=mode, temper=tau)
    labels = torch.arange(C).view(-1, 1, 1).expand(calib.shape[:3])
    for kind, key in (("matrix", "calibrated"), ("temperature", "calibrated_temperature")):
        # the calibrated peer: per-frame calibration on the same labelled frames, then SSBF with its evidence weight
        peer = hbni_pyro.make_filter("calibrated", calibration=hbni_pyro.fit_frame_calibration(calib, labels, kind))
        filters[key] = peer.tempered(hbni_pyro.fit_temper(peer, calib_streams, calib_truth).temper)
    for baseline in BASELINES:
        filters[baseline] = hbni_pyro.make_filter(baseline, num_classes=M)
    return filters


def _class_names(condition: str) -> list[str] | None:
    """The classes of a condition's outputs (a user's folder: its own, unnamed here)."""
    return {"images": None, "photos": list(PHOTOS)}.get(condition, list(CLASSES))


def score_filter(
    f: Any,
    streams: torch.Tensor,
    truth: torch.Tensor,
    thresholds: list[float],
    curve: list[float],
    stops: dict[float, float] | None = None,
) -> dict[str, Any]:
    """Held-out log score, final accuracy, reliability and the macro-observation checks of one filter (stopping at
    ``stops[t]`` for threshold ``t`` where given)."""
    probs = f.run(streams)
    true_prob = probs.gather(-1, truth.view(-1, 1, 1).expand(-1, probs.shape[1], 1)).squeeze(-1)
    final = float((hbni_pyro.decide(probs[:, -1]) == truth).to(DTYPE).mean())
    rel = stream_reliability(f, streams, truth)
    return {
        "log_score": float(true_prob.clamp_min(1e-300).log().mean()),
        "log_score_stderr": float(true_prob.clamp_min(1e-300).log().mean(1).std() / math.sqrt(len(truth))),
        "final_accuracy": final,
        "final_stderr": binomial_stderr(final, len(truth)),
        "ece": rel.ece,
        "reliability": {"confidence": rel.confidence, "accuracy": rel.accuracy, "count": rel.count},
        "thresholds": threshold_checks(f, streams, truth, thresholds, stops=stops),
        "curve": threshold_checks(f, streams, truth, curve),
    }


# -- 4. acceptance --------------------------------------------------------------------------------


def acceptance(toy: dict[str, Any], conditions: dict[str, Any], models: list[str]) -> dict[str, Any]:
    """The issue's floors for the best model of each condition (highest held-out log score)."""
    out: dict[str, Any] = {"toy": {}}
    paper_n = toy["crossing_n"].get("paper")
    for model in models:
        n = toy["crossing_n"][model]
        out["toy"][model] = {
            "n": n,
            "paper_n": paper_n,
            "within_one_frame": n is not None and paper_n is not None and n <= paper_n + 1,
        }
    for name, cond in conditions.items():
        rows = cond["filters"]
        best = max(models, key=lambda m: rows[m]["log_score"])
        b, ssbf = rows[best], rows["ssbf"]
        entry: dict[str, Any] = {"best_model": best}
        for t, row in b["thresholds"].items():
            entry[f"honest_at_{t}"] = row["emitted_accuracy"] >= float(t) - 0.03
        at95 = b["thresholds"].get("0.95")
        if at95:
            s95 = ssbf["thresholds"]["0.95"]
            ratio = at95["mean_frames"] / s95["mean_frames"]
            entry["timeouts_at_0.95"], entry["timeouts_stderr"] = at95["timeout_rate"], at95["timeout_stderr"]
            entry["frames_over_ssbf_at_0.95"] = ratio
            entry["frames_ratio_stderr"] = ratio * math.hypot(
                at95["frames_stderr"] / at95["mean_frames"], s95["frames_stderr"] / s95["mean_frames"]
            )
            entry["not_timid"] = entry["timeouts_at_0.95"] <= 0.15 and ratio <= 1.5
        if "paper" in rows and best != "paper":
            p = rows["paper"]
            se = math.sqrt(b["final_stderr"] ** 2 + p["final_stderr"] ** 2)
            entry["final_accuracy_gain_over_paper"] = b["final_accuracy"] - p["final_accuracy"]
            entry["gain_stderr"] = se
            entry["beats_paper_outside_stderr"] = entry["final_accuracy_gain_over_paper"] > se
        if name == "photos" and "sequence" in rows:
            entry["sequence_target"] = _photo_target(rows["sequence"], ssbf)
        if f"{DEFAULT_MODEL}_stopped" in rows and "calibrated" in rows:
            entry["default_vs_calibrated"] = default_vs_peer(rows[f"{DEFAULT_MODEL}_stopped"], rows["calibrated"])
        out[name] = entry
    return out


def default_vs_peer(default: dict[str, Any], peer: dict[str, Any], threshold: str = "0.95") -> dict[str, Any]:
    """The default (the sequence model, calibrated stop) against the calibrated peer at ``threshold``: its emitted
    labels right at least ``threshold`` within one binomial s.e., mean frames at most 1.5 times the peer's,
    timeouts at most 10 %."""
    a, b = default["thresholds"].get(threshold), peer["thresholds"].get(threshold)
    if a is None or b is None:
        return {}
    out = {
        "emitted_accuracy": a["emitted_accuracy"],
        "emitted_stderr": a["emitted_stderr"],
        "mean_frames": a["mean_frames"],
        "peer_mean_frames": b["mean_frames"],
        "peer_emitted_accuracy": b["emitted_accuracy"],
        "frames_over_peer": a["mean_frames"] / b["mean_frames"],
        "timeout_rate": a["timeout_rate"],
        "stop": a.get("stop"),
    }
    out["honest"] = a["emitted"] > 0 and a["emitted_accuracy"] + a["emitted_stderr"] >= float(threshold)
    out["frames_at_most_1.5x_peer"] = out["frames_over_peer"] <= 1.5
    out["timeouts_at_most_0.1"] = a["timeout_rate"] <= 0.10
    out["met"] = out["honest"] and out["frames_at_most_1.5x_peer"] and out["timeouts_at_most_0.1"]
    return out


def _photo_target(seq: dict[str, Any], ssbf: dict[str, Any]) -> dict[str, Any]:
    """The default model's target on the photographs at threshold 0.95: emitted labels right at least
    0.95 of the time, timeouts at most 10 %, mean frames at most SSBF's."""
    a, b = seq["thresholds"].get("0.95"), ssbf["thresholds"].get("0.95")
    if a is None:
        return {}
    right, timeouts, frames = (
        a["emitted_accuracy"] >= 0.95,
        a["timeout_rate"] <= 0.10,
        a["mean_frames"] <= b["mean_frames"],
    )
    return {
        "emitted_right": right,
        "timeouts_at_most_0.1": timeouts,
        "frames_at_most_ssbf": frames,
        "met": right and timeouts and frames,
    }


def honesty(condition: dict[str, Any]) -> dict[str, dict[str, bool]]:
    """Per filter and threshold ``t``: whether the emitted labels are right at least ``t - 0.03`` of the time
    (``False`` when none is emitted)."""
    return {
        name: {t: v["emitted"] > 0 and v["emitted_accuracy"] >= float(t) - 0.03 for t, v in row["thresholds"].items()}
        for name, row in condition["filters"].items()
    }
