"""The mission's report and figures: values per perception variant, macro-observation tables, curves."""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
import numpy as np

import hbni_pyro
from decpomdp.domains.disaster_relief import CLASSES
from experiments.reports import figures
from experiments.reports.scores import beats, ratio

LABELS = figures.LABELS


def _explanation(metrics: dict) -> list[str]:
    """Why HBNI's policy does or does not beat another process's, in the numbers that decide it."""
    v = metrics["variants"]
    if "hbni" not in v:
        return []
    planning = metrics.get("closed_loop", {}).get("planning", {}).get("hbni", "empirical")
    sizes = metrics["sizes"]
    n = sizes["generative_streams_per_class"] if planning == "generative" else sizes["held_out_streams"] / len(CLASSES)
    h = v["hbni"]
    acc_h, frames_h = float(np.mean(h["macro_accuracy"])), float(np.mean(h["macro_mean_frames"]))
    out = []
    for other in ("calibrated", "ssbf", "max_of_mean"):
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


def _planning_line(metrics: dict) -> str:
    """How the policies were searched."""
    first = "the paper's G-DICE" if metrics["planner"]["ce_result"] == "best_sampled" else "the cold-start planner"
    if metrics.get("warm_planner"):
        return (
            f"Policies searched with no hand-written controller: {first} planned perfect perception "
            f"from scratch ({metrics['planner']['budget'] / 1e6:g}M rollouts), then refined that plan for each perception "
            f"variant ({metrics['warm_planner']['budget'] / 1e6:g}M rollouts each); every policy is re-evaluated on "
            "independent rollouts."
        )
    return (
        f"Policies searched from scratch with {first} ({metrics['planner']['budget'] / 1e6:g}M rollouts "
        "each) and re-evaluated on independent rollouts."
    )


def report(metrics: dict, figures: list[str]) -> str:
    rows = [
        "| perception | planned value (± s.e.) | delivered / run | wrong / run | wrong rate | mean inference frames "
        "| greedy policy value (± s.e.) | planned - greedy (s.e.) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in metrics["variants"].items():
        rows.append(
            f"| {LABELS[name]} | {r['value']:.3f} ± {r['stderr']:.3f} | {r['delivered_per_rollout']:.2f} | "
            f"{r['wrong_per_rollout']:.2f} | {r['wrong_rate']:.3f} | {r['mean_inference_frames']:.1f} | "
            f"{r['greedy']['value']:.3f} ± {r['greedy']['stderr']:.3f} | {over_greedy(r):+.1f} |"
        )
    macro = ["| process | label accuracy (mean over classes) | mean frames | timed out |", "|---|---|---|---|"]
    for name, r in metrics["variants"].items():
        if name != "perfect":
            macro.append(
                f"| {LABELS[name]} | {float(np.mean(r['macro_accuracy'])):.3f} | "
                f"{float(np.mean(r['macro_mean_frames'])):.1f} | {float(np.mean(r['macro_timed_out'])):.3f} |"
            )
    acc = metrics["acceptance"]
    explain = _explanation(metrics)
    temper = metrics["hbni_temper"]
    how = "fitted by log score on the labelled calibration sequences" if temper["fitted"] else "set in the config"
    temper_line = (
        "HBNI's noise model is the sequence-aware one: it integrates each sequence's look out and uses no "
        "likelihood temper; its generative streams correlate consecutive frames about their look by "
        f"{metrics.get('hbni_frame_correlation', 0.0):.2f}, as the calibration sequences do."
        if temper.get("needed") is False
        else f"HBNI's likelihood temper is {temper['value']:g} ({how}; 1 treats a sequence's frames as independent)."
    )
    lines = [
        "# Mission report: disaster relief on semantic macro-observations",
        "",
        _planning_line(metrics),
        f"Frames: the `mission` imaging preset{_overrides(metrics['conditions']['overrides'])}.",
        "",
        *rows,
        "",
        "Macro-observation processes as each policy plans on them (an empirical table: held-out classifier output "
        "streams; a generative one: streams simulated from the fitted noise model):",
        "",
        *macro,
        "",
        temper_line,
        "",
        *explain,
    ]
    if acc:
        lines += [
            "Checks: "
            + ", ".join(f"`{k}` = {v:.3f}" if isinstance(v, float) else f"`{k}` = {v}" for k, v in acc.items()),
            "",
        ]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def over_greedy(entry: dict) -> float:
    """(planned - greedy) / the standard error of the difference, on the variant's own planning model."""
    g = entry["greedy"]
    return (entry["value"] - g["value"]) / (entry["stderr"] ** 2 + g["stderr"] ** 2) ** 0.5


def value_figure(results: dict[str, dict]) -> plt.Figure:
    names = list(results)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    ticks = [figures.label(n) for n in names]
    axes[0].bar(
        ticks,
        [results[n]["value"] for n in names],
        yerr=[results[n]["stderr"] for n in names],
        capsize=4,
        color=[figures.color(n) for n in names],
    )
    axes[0].scatter(
        ticks,
        [results[n]["greedy"]["value"] for n in names],
        marker="_",
        s=900,
        color="black",
        zorder=3,
        label="greedy controller",
    )
    axes[0].legend(fontsize=figures.TICK_SIZE, loc="lower right", markerscale=0.3)
    axes[0].set_ylabel("discounted return (mean ± s.e.)", fontsize=figures.LABEL_SIZE)
    axes[0].set_title("Planned value per policy (on its planning model)", fontsize=figures.TITLE_SIZE)
    x = np.arange(len(names))
    colors = [figures.color(n) for n in names]
    axes[1].bar(
        x - 0.2,
        [results[n]["delivered_per_rollout"] for n in names],
        0.4,
        color=colors,
        label="delivered right (solid)",
    )
    axes[1].bar(
        x + 0.2,
        [results[n]["wrong_per_rollout"] for n in names],
        0.4,
        color=colors,
        alpha=0.35,
        hatch="//",
        label="delivered wrong (hatched)",
    )
    axes[1].set_xticks(x, ticks)
    axes[1].set_ylabel("objects per mission", fontsize=figures.LABEL_SIZE)
    axes[1].set_ylim(top=1.3 * max(results[n]["delivered_per_rollout"] for n in names))  # room for the legend
    axes[1].legend(fontsize=figures.TICK_SIZE, ncol=2)
    axes[1].set_title("Deliveries", fontsize=figures.TITLE_SIZE)
    for ax in axes:
        ax.tick_params(axis="x", labelsize=figures.TICK_SIZE)
        plt.setp(ax.get_xticklabels(), rotation=15, ha="right")
    fig.tight_layout()
    return fig


def confusion_figure(models: dict[str, hbni_pyro.MacroObservationModel]) -> plt.Figure:
    fig, axes = figures.panels(len(models))
    ticks = [c.replace("_", " ") for c in CLASSES]
    for k, (ax, (name, model)) in enumerate(zip(axes, models.items())):
        image = figures.heatmap(ax, model.confusion.numpy(), ticks, f"{figures.label(name)}: P(label | true class)")
        ax.set_xlabel("macro-observation label", fontsize=figures.LABEL_SIZE)
        if k % figures.PANEL_COLUMNS == 0:
            ax.set_ylabel("true class", fontsize=figures.LABEL_SIZE)
        else:  # one set of class names per row
            ax.set_yticklabels([])
    fig.tight_layout()
    fig.colorbar(image, ax=axes, shrink=0.8, label="probability")
    return fig


def frames_figure(models: dict[str, hbni_pyro.MacroObservationModel]) -> plt.Figure:
    fig, axes = figures.panels(len(models), height=3.6, sharey=True)
    for k, (ax, (name, model)) in enumerate(zip(axes, models.items())):
        support = np.arange(1, model.max_frames + 1)
        for c, cls in enumerate(CLASSES):
            ax.plot(support, model.frames_pmf[c].numpy(), marker=".", lw=1, label=cls.replace("_", " "))
        ax.set_xlabel("frames used", fontsize=figures.LABEL_SIZE)
        ax.set_title(f"{figures.label(name)}: P(frames | true class)", fontsize=figures.TITLE_SIZE)
        ax.tick_params(labelsize=figures.TICK_SIZE)
        if k % figures.PANEL_COLUMNS == 0:
            ax.set_ylabel("probability", fontsize=figures.LABEL_SIZE)
    axes[0].legend(fontsize=figures.TICK_SIZE - 1, title="true class")
    fig.tight_layout()
    return fig


def curves_figure(histories: dict[str, dict], offsets: dict[str, float] | None = None) -> plt.Figure:
    """Learning curves: each planner run's incumbent value against rollouts (G-DICE: its best sample so far).

    ``offsets``: rollouts spent before a run started (a run warm-started from another run's plan continues its curve).
    """
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    offsets = offsets or {}
    for name, h in histories.items():
        # the incumbent after each step; a G-DICE run has one only at its end, so its best sample so far instead
        key = "value" if sum(v == v for v in h["value"]) > 1 else "best_sampled"
        points = [((offsets.get(name, 0) + r) / 1e6, v) for r, v in zip(h["rollouts"], h[key]) if v == v]
        if points:
            ax.step(
                *zip(*points),
                where="post",
                color=figures.color(name),
                label=figures.label(name) + (" (best sampled)" if key != "value" else ""),
            )
    ax.set_xlabel("rollouts spent (millions)")
    ax.set_ylabel("incumbent value on fresh rollouts")
    ax.set_title("Planner learning curves")
    ax.legend(fontsize=8)
    return fig


def acceptance(results: dict[str, dict]) -> dict[str, Any]:
    """HBNI's policy against perfect perception and every other variant's (their values in standard errors, wrong
    deliveries against SSBF's)."""
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
