"""The mission end to end: pixels -> classifier outputs -> HBNI macro-observations -> Dec-POSMDP policy.

1. Render training-condition snapshots and mission-condition sequences of the six
   disaster-relief object types (``classifiers.data``).
2. Train the :class:`~classifiers.FrameClassifier` head on the snapshots (crops and mirrors)
   and classify every mission frame.
3. Fit HBNI on labelled calibration sequences' outputs, then its likelihood temper on the
   same sequences (:func:`hbni_pyro.fit_temper`: their frames are correlated, not i.i.d.).
4. Run HBNI, SSBF and max-of-mean macro-observation processes (threshold, frame budget) on
   held-out output streams and tabulate each one's ``P(label, frames | true class)``: the
   :class:`~hbni_pyro.MacroObservationModel` of the "infer with 95 % confidence" MA.
5. Plug each model (and perfect perception) into the disaster-relief domain, search a
   controller with G-DICE (seeded with the hand-written greedy controller when
   ``planner.init_weight > 0``), and re-evaluate it, and the greedy controller itself,
   on independent rollouts.

Writes ``metrics.json``, ``report.md`` with the figures ``values.png``, ``confusion.png``,
``frames.png`` and ``learning_curves.png``, and every fitted artefact (``artifacts.json``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf
from tqdm.auto import tqdm

import hbni_pyro
from classifiers.data import get_conditions
from decpomdp import GDICEConfig
from decpomdp.domains.disaster_relief import CLASSES
from experiments.artifacts import save_artifact
from experiments.common import beats, save_figure
from decpomdp.policies import disaster_relief_greedy
from experiments.package_delivery import run_gdice, score, seed_controller
from experiments.perception_replay import sequence_outputs, train_classifier
from experiments.report import write_report

VARIANTS = ("hbni", "ssbf", "max_of_mean")
LABELS = {"perfect": "perfect perception", "hbni": "HBNI", "ssbf": "SSBF", "max_of_mean": "max-of-mean"}


def run(cfg: DictConfig, run_dir: Path) -> dict:
    seed, progress = int(cfg.seed), bool(cfg.progress)
    variants = _variants(cfg.perception)
    st = cfg.mission
    fixed_temper = _temper_setting(st.temper)
    overrides = OmegaConf.to_container(st.conditions) if st.conditions else {}
    mission = get_conditions("mission", **overrides)
    torch.manual_seed(seed)
    _step(progress, "1/5 training the frame classifier on training-condition snapshots")
    clf = train_classifier(cfg.classifier, CLASSES, int(st.train_per_class), int(st.augment), seed, progress)
    save_artifact(run_dir, "classifier", clf)
    order = [clf.classes_.index(name) for name in CLASSES]
    frames = int(st.frames)

    _step(progress, "2/5 classifying mission-condition frames")
    calib = sequence_outputs(clf, CLASSES, int(st.calib_sequences), frames, mission, seed + 1, progress, "calibration")[0]
    held = sequence_outputs(clf, CLASSES, int(st.char_sequences), frames, mission, seed + 2, progress, "held-out")[0]
    calib, held = calib[..., order].double(), held[..., order].double()

    _step(progress, "3/5 fitting HBNI and its frame-correlation temper on labelled calibration outputs")
    M = len(CLASSES)
    labels = torch.arange(M).view(-1, 1, 1).expand(calib.shape[:3]).reshape(-1)
    posterior = hbni_pyro.fit(
        calib.reshape(-1, M), labels, **OmegaConf.to_container(cfg.hbni.fit),
        hyperprior=instantiate(cfg.hbni.hyperprior), seed=seed, progress=progress,
    )
    save_artifact(run_dir, "posterior", posterior)
    calib_truth = torch.arange(M).repeat_interleave(calib.shape[1])
    if fixed_temper is None:
        fitted = hbni_pyro.fit_temper(posterior, calib.reshape(-1, frames, M), calib_truth, cfg.hbni.filter.mode)
        temper = {"value": fitted.temper, "fitted": True, "grid": fitted.grid.tolist(), "log_score": fitted.log_score.tolist()}
    else:
        temper = {"value": fixed_temper, "fitted": False}

    _step(progress, "4/5 characterising the macro-observation processes on held-out streams")
    streams = held.reshape(-1, frames, M)
    truth = torch.arange(M).repeat_interleave(held.shape[1])
    filters = {
        "hbni": hbni_pyro.HBNIFilter(posterior, mode=cfg.hbni.filter.mode, temper=temper["value"]),
        "ssbf": hbni_pyro.SSBF(M),
        "max_of_mean": hbni_pyro.MaxOfMeanFilter(M),
    }
    models = {}
    for name in variants:
        process = hbni_pyro.MacroObservationProcess(filters[name], threshold=float(st.threshold), max_frames=frames)
        models[name] = hbni_pyro.macro.tabulate(process, streams, truth)
        save_artifact(run_dir, f"macro_{name}", models[name])

    _step(progress, "5/5 planning with G-DICE on the disaster-relief domain")
    planner: GDICEConfig = instantiate(cfg.planner)
    results: dict[str, Any] = {}
    histories = {}
    threads = torch.get_num_threads()
    torch.set_num_threads(int(cfg.study.threads))
    for k, name in enumerate(("perfect", *variants)):
        env = instantiate(cfg.domain, perception=None if name == "perfect" else models[name])
        greedy = disaster_relief_greedy(env.num_agents)
        init = seed_controller(greedy, bool(cfg.study.shared_controller)) if planner.init_weight > 0 else None
        result, best, seconds = run_gdice(env, planner, cfg.study, seed + 10 * k, progress, init=init)
        save_artifact(run_dir, f"controller_{name}", best)
        entry = score(env, best, int(cfg.study.reeval_rollouts), seed + 10 * k + 5)
        entry.update(best_sampled=result.best_value, search_seconds=seconds)
        hand = score(env, greedy, int(cfg.study.reeval_rollouts), seed + 10 * k + 6)
        entry["greedy"] = {key: hand[key] for key in ("value", "stderr", "delivered_per_rollout", "wrong_per_rollout")}
        entry["wrong_rate"] = entry["wrong_per_rollout"] / max(entry["wrong_per_rollout"] + entry["delivered_per_rollout"], 1e-12)
        entry["mean_inference_frames"] = entry["inference_frames_per_rollout"] / max(entry["inferences_per_rollout"], 1e-12)
        if name != "perfect":
            entry["macro_accuracy"] = models[name].accuracy.tolist()
            entry["macro_mean_frames"] = models[name].mean_frames.tolist()
            entry["macro_timed_out"] = models[name].timed_out.tolist()
        results[name] = entry
        histories[name] = result.history
    torch.set_num_threads(threads)

    figures = {
        "values.png": _value_figure(results),
        "confusion.png": _confusion_figure(models),
        "frames.png": _frames_figure(models),
        "learning_curves.png": _curves_figure(histories),
    }
    for file, fig in figures.items():
        save_figure(fig, run_dir / file)
    metrics = {
        "classes": CLASSES,
        "variants": results,
        "acceptance": _acceptance(results),
        "classifier_frame_accuracy": _frame_accuracy(held),
        "conditions": {"preset": "mission", "overrides": overrides},
        "hbni_temper": temper,
        "theta_summary": {k: v for k, v in posterior.summary().items() if k.startswith("theta")},
        "planner": dataclasses.asdict(planner),
        "wrong_penalty": float(cfg.domain.wrong_penalty),
        "frame_period": float(cfg.domain.frame_period),
        "sizes": {
            "train_snapshots_per_class": int(st.train_per_class), "calibration_frames": int(labels.numel()),
            "held_out_streams": int(truth.numel()), "frames_per_stream": frames,
        },
    }
    write_report(run_dir / "report.md", _report(metrics, list(figures)))
    return metrics


def _variants(perception: Any) -> list[str]:
    chosen = list(perception) if isinstance(perception, (list, tuple, ListConfig)) else [str(perception)]
    unknown = [v for v in chosen if v not in VARIANTS]
    if unknown or not chosen:
        raise ValueError(f"perception: expected a subset of {list(VARIANTS)}, got {chosen}")
    return chosen


def _temper_setting(setting: Any) -> float | None:
    """``mission.temper``: ``"fit"`` (``None``: fit on the calibration streams) or a float in (0, 1]."""
    if setting == "fit":
        return None
    if isinstance(setting, bool) or not isinstance(setting, (int, float)) or not 0 < setting <= 1:
        raise ValueError(f"mission.temper: expected 'fit' or a float in (0, 1], got {setting!r}")
    return float(setting)


def _step(progress: bool, message: str) -> None:
    if progress:
        tqdm.write(f"[mission] {message}")


def _frame_accuracy(outputs: torch.Tensor) -> dict[str, float]:
    return {name: float((outputs[c].argmax(-1) == c).double().mean()) for c, name in enumerate(CLASSES)}


def _acceptance(results: dict[str, dict]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if "hbni" not in results:
        return out
    h = results["hbni"]
    out["hbni_over_perfect"] = _ratio(h["value"], results["perfect"]["value"])
    for other in ("ssbf", "max_of_mean"):
        if other in results:
            o = results[other]
            out[f"hbni_beats_{other}_outside_stderr"] = beats(h, o)
            out[f"hbni_minus_{other}_in_stderr"] = _ratio(h["value"] - o["value"], (h["stderr"] ** 2 + o["stderr"] ** 2) ** 0.5)
    if "ssbf" in results:
        out["hbni_wrong_rate_below_ssbf"] = h["wrong_rate"] < results["ssbf"]["wrong_rate"]
    return out


def _explanation(metrics: dict) -> list[str]:
    """Why HBNI's policy does or does not beat another process's, in the numbers that decide it."""
    v = metrics["variants"]
    if "hbni" not in v:
        return []
    n = metrics["sizes"]["held_out_streams"] / len(CLASSES)
    h = v["hbni"]
    acc_h, frames_h = float(np.mean(h["macro_accuracy"])), float(np.mean(h["macro_mean_frames"]))
    out = []
    for other in ("ssbf", "max_of_mean"):
        if other not in v:
            continue
        o = v[other]
        acc_o, frames_o = float(np.mean(o["macro_accuracy"])), float(np.mean(o["macro_mean_frames"]))
        se = ((acc_h * (1 - acc_h) + acc_o * (1 - acc_o)) / (n * len(CLASSES))) ** 0.5
        verdict = "beats" if beats(h, o) else "does not beat"
        out.append(
            f"HBNI {verdict} {LABELS[other]} ({h['value']:.3f} vs {o['value']:.3f}). Its macro-observations are right "
            f"{acc_h:.1%} of the time after {frames_h:.1f} frames, against {acc_o:.1%} after {frames_o:.1f} frames "
            f"(accuracy difference {acc_h - acc_o:+.1%}, binomial s.e. {se:.1%} from {int(n)} streams per class); "
            f"each wrong label costs a wrong delivery (penalty {metrics['wrong_penalty']:g}) and each frame "
            f"{metrics['frame_period']:g} time units of the robot's mission."
        )
    return out + [""]


def _overrides(overrides: dict) -> str:
    return " with " + ", ".join(f"{k} = {v}" for k, v in overrides.items()) if overrides else ""


def _ratio(a: float, b: float) -> float:
    return a / b if b else float("nan")


def _report(metrics: dict, figures: list[str]) -> str:
    rows = ["| perception | G-DICE value (± s.e.) | delivered / run | wrong / run | wrong rate | mean inference frames "
            "| greedy policy value (± s.e.) |", "|---|---|---|---|---|---|---|"]
    for name, r in metrics["variants"].items():
        rows.append(
            f"| {LABELS[name]} | {r['value']:.3f} ± {r['stderr']:.3f} | {r['delivered_per_rollout']:.2f} | "
            f"{r['wrong_per_rollout']:.2f} | {r['wrong_rate']:.3f} | {r['mean_inference_frames']:.1f} | "
            f"{r['greedy']['value']:.3f} ± {r['greedy']['stderr']:.3f} |"
        )
    macro = ["| process | label accuracy (mean over classes) | mean frames | timed out |", "|---|---|---|---|"]
    for name, r in metrics["variants"].items():
        if name != "perfect":
            macro.append(f"| {LABELS[name]} | {float(np.mean(r['macro_accuracy'])):.3f} | "
                         f"{float(np.mean(r['macro_mean_frames'])):.1f} | {float(np.mean(r['macro_timed_out'])):.3f} |")
    acc = metrics["acceptance"]
    explain = _explanation(metrics)
    temper = metrics["hbni_temper"]
    how = "fitted by log score on the labelled calibration sequences" if temper["fitted"] else "set in the config"
    lines = [
        "# Mission report: disaster relief on semantic macro-observations", "",
        "Policies searched with G-DICE for each perception variant and re-evaluated on independent rollouts.",
        f"Frames: the `mission` imaging preset{_overrides(metrics['conditions']['overrides'])}.", "",
        *rows, "", "Macro-observation processes characterised on held-out classifier output streams:", "", *macro, "",
        f"HBNI's likelihood temper is {temper['value']:g} ({how}; 1 treats a sequence's frames as independent).", "",
        *explain,
    ]
    if acc:
        lines += ["Checks: " + ", ".join(f"`{k}` = {v:.3f}" if isinstance(v, float) else f"`{k}` = {v}" for k, v in acc.items()), ""]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def _value_figure(results: dict[str, dict]) -> plt.Figure:
    names = list(results)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    colors = ["tab:gray", "tab:blue", "tab:orange", "tab:green"][: len(names)]
    axes[0].bar([LABELS[n] for n in names], [results[n]["value"] for n in names],
                yerr=[results[n]["stderr"] for n in names], capsize=4, color=colors)
    axes[0].set_ylabel("discounted return (mean ± s.e.)")
    axes[0].set_title("Policy value per perception variant")
    x = np.arange(len(names))
    axes[1].bar(x - 0.2, [results[n]["delivered_per_rollout"] for n in names], 0.4, label="delivered right")
    axes[1].bar(x + 0.2, [results[n]["wrong_per_rollout"] for n in names], 0.4, label="delivered wrong", color="tab:red")
    axes[1].set_xticks(x, [LABELS[n] for n in names])
    axes[1].set_ylabel("objects per mission")
    axes[1].legend(fontsize=8)
    axes[1].set_title("Deliveries")
    for ax in axes:
        ax.tick_params(axis="x", labelsize=8)
    fig.tight_layout()
    return fig


def _confusion_figure(models: dict[str, hbni_pyro.MacroObservationModel]) -> plt.Figure:
    fig, axes = plt.subplots(1, len(models), figsize=(4.2 * len(models), 4), squeeze=False)
    short = [c.replace("_", "\n") for c in CLASSES]
    for ax, (name, model) in zip(axes[0], models.items()):
        conf = model.confusion.numpy()
        ax.imshow(conf, vmin=0, vmax=1, cmap="Blues")
        for i in range(conf.shape[0]):
            for j in range(conf.shape[1]):
                ax.text(j, i, f"{conf[i, j]:.2f}", ha="center", va="center", fontsize=7,
                        color="white" if conf[i, j] > 0.6 else "black")
        ax.set_xticks(range(len(CLASSES)), short, fontsize=6)
        ax.set_yticks(range(len(CLASSES)), short, fontsize=6)
        ax.set_xlabel("macro-observation label")
        ax.set_title(f"{LABELS[name]}: P(label | true class)", fontsize=9)
    axes[0][0].set_ylabel("true class")
    fig.tight_layout()
    return fig


def _frames_figure(models: dict[str, hbni_pyro.MacroObservationModel]) -> plt.Figure:
    fig, axes = plt.subplots(1, len(models), figsize=(4.2 * len(models), 3.4), squeeze=False, sharey=True)
    for ax, (name, model) in zip(axes[0], models.items()):
        support = np.arange(1, model.max_frames + 1)
        for c, cls in enumerate(CLASSES):
            ax.plot(support, model.frames_pmf[c].numpy(), marker=".", lw=1, label=cls)
        ax.set_xlabel("frames used")
        ax.set_title(f"{LABELS[name]}: P(frames | true class)", fontsize=9)
    axes[0][0].set_ylabel("probability")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    return fig


def _curves_figure(histories: dict[str, dict]) -> plt.Figure:
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for name, h in histories.items():
        its = np.arange(1, len(h["best"]) + 1)
        line, = ax.plot(its, h["best"], label=f"{LABELS[name]}: best so far")
        ax.plot(its, h["iteration_mean"], color=line.get_color(), alpha=0.4, ls="--")
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("value (Monte Carlo estimate)")
    ax.set_title("G-DICE learning curves (dashed: iteration mean)")
    ax.legend(fontsize=8)
    return fig
