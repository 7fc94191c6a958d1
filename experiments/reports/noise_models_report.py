"""The noise-model study's report and figures: toy error curves, accuracy against mean frames,
reliability diagrams, and a table per imaging condition."""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
import numpy as np

LABELS = {
    "paper": "HBNI, paper's model",
    "paper_tempered": "HBNI, paper's + temper",
    "confusion": "HBNI, confusion-aware",
    "confusion_tempered": "HBNI, confusion-aware + temper",
    "sequence": "HBNI, sequence-aware",
    "sequence_stopped": "HBNI, sequence-aware, calibrated stop (the default)",
    "calibrated": "calibrated (matrix) + SSBF",
    "calibrated_temperature": "calibrated (temperature) + SSBF",
    "ssbf": "SSBF",
    "max_of_mean": "max of mean",
}
STYLE = {
    "paper": ("tab:blue", "-"),
    "paper_tempered": ("tab:blue", "--"),
    "confusion": ("tab:purple", "-"),
    "confusion_tempered": ("tab:purple", "--"),
    "sequence": ("tab:red", "-"),
    "sequence_stopped": ("tab:red", ":"),
    "calibrated": ("tab:brown", "-"),
    "calibrated_temperature": ("tab:brown", "--"),
    "ssbf": ("tab:green", "-"),
    "max_of_mean": ("tab:orange", "-"),
}
CONDITION_TITLES = {
    "default": "default mission conditions",
    "in_flight": "in-flight preset",
    "images": "user image folder",
    "photos": "real photographs, degraded moving camera",
}


def _label(name: str) -> str:
    return LABELS.get(name, name)


def _title(name: str) -> str:
    return CONDITION_TITLES.get(name, name)


def toy_figure(toy: dict[str, Any]) -> plt.Figure:
    """Error against the number of outputs N on the paper's toy, log scale, with the target line."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    floor = 0.5 / toy["trials"]
    for name, err in toy["error"].items():
        e = np.asarray(err, dtype=float)
        n = np.arange(1, len(e) + 1)
        color, ls = STYLE.get(name, ("k", "-"))
        cross = toy["crossing_n"][name]
        ax.plot(
            n,
            np.where(e > 0, e, np.nan),
            ls,
            color=color,
            lw=1.8,
            label=f"{_label(name)} (N = {cross if cross is not None else '> ' + str(len(e))})",
        )
    ax.axhline(toy["target"], color="k", lw=0.7, ls=":")
    ax.set_yscale("log")
    ax.set_ylim(floor, 1)
    ax.set_xlabel("number of outputs N")
    ax.set_ylabel(f"classification error ({toy['trials']} trials)")
    theta = ", ".join(f"{float(t):g}" for t in toy["true_theta"])
    ax.set_title(
        f"Paper's toy: θ = ({theta}), {toy['training_size']} unlabelled training outputs ({toy['training_sets']} "
        f"sets); N to {toy['target']:.0%} error in the legend; zero error leaves a gap",
        fontsize=9,
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def curve_figure(conditions: dict[str, Any]) -> plt.Figure:
    """Per condition: accuracy of the emitted labels against mean frames used, one point per threshold."""
    fig, axes = plt.subplots(1, len(conditions), figsize=(5.6 * len(conditions), 4.4), squeeze=False)
    for ax, (cond, data) in zip(axes[0], conditions.items()):
        for name, row in data["filters"].items():
            pts = sorted((v["mean_frames"], v["emitted_accuracy"], float(t)) for t, v in row["curve"].items())
            color, ls = STYLE.get(name, ("k", "-"))
            ax.plot([p[0] for p in pts], [p[1] for p in pts], ls, marker=".", color=color, lw=1.5, label=_label(name))
            at95 = row["curve"].get("0.95")
            if at95:
                ax.plot(at95["mean_frames"], at95["emitted_accuracy"], "o", color=color, ms=7, mfc="white")
        ax.set_xlabel("mean frames used (a timeout counts the whole budget)")
        ax.set_ylabel("accuracy of the emitted labels")
        ax.set_title(f"{_title(cond)} ({data['sizes']['held_out_sequences']} held-out sequences)", fontsize=10)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.suptitle("Accuracy against frames: thresholds 0.5 to 0.995 (open circle: 0.95)", y=1.01)
    fig.tight_layout()
    return fig


def reliability_figure(conditions: dict[str, Any]) -> plt.Figure:
    """Per condition: reliability diagrams (accuracy against stated confidence over every prefix)."""
    fig, axes = plt.subplots(1, len(conditions), figsize=(5 * len(conditions), 4.6), squeeze=False)
    for ax, (cond, data) in zip(axes[0], conditions.items()):
        ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")
        for name, row in data["filters"].items():
            rel = row["reliability"]
            conf, acc = np.asarray(rel["confidence"], dtype=float), np.asarray(rel["accuracy"], dtype=float)
            used = np.isfinite(conf)
            color, ls = STYLE.get(name, ("k", "-"))
            ax.plot(
                conf[used],
                acc[used],
                ls,
                marker=".",
                color=color,
                lw=1.5,
                label=f"{_label(name)} (ECE {row['ece']:.3f})",
            )
        ax.set_xlim(0.1, 1.01)
        ax.set_ylim(0, 1.01)
        ax.set_xlabel("stated confidence (top posterior probability)")
        ax.set_ylabel("accuracy")
        ax.set_title(_title(cond), fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig


def _fmt_n(n: Any) -> str:
    return "-" if n is None else str(n)


def condition_table(data: dict[str, Any], thresholds: list[str]) -> list[str]:
    head = "| filter | held-out log score | accuracy after all frames | ECE |" + "".join(
        f" emitted right at {t} | timeouts | frames |" for t in thresholds
    )
    lines = [head, "|" + "---|" * (4 + 3 * len(thresholds))]
    for name, r in data["filters"].items():
        cells = [
            f"{_label(name)}",
            f"{r['log_score']:.3f} ± {r['log_score_stderr']:.3f}",
            f"{r['final_accuracy']:.3f} ± {r['final_stderr']:.3f}",
            f"{r['ece']:.3f}",
        ]
        for t in thresholds:
            v = r["thresholds"][t]
            acc = "-" if v["emitted"] == 0 else f"{v['emitted_accuracy']:.3f} ± {v['emitted_stderr']:.3f}"
            cells += [
                acc,
                f"{v['timeout_rate']:.3f} ± {v['timeout_stderr']:.3f}",
                f"{v['mean_frames']:.1f} ± {v['frames_stderr']:.1f}",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def markdown(metrics: dict[str, Any], figures: list[str]) -> str:
    toy, acc = metrics["toy"], metrics["acceptance"]
    lines = [
        "# Noise models: paper, confusion-aware and sequence-aware HBNI",
        "",
        f"## The paper's toy ({toy['training_size']} unlabelled training outputs, {toy['trials']} trials)",
        "",
        "| filter | smallest N with error at most " + f"{toy['target']:.0%} |",
        "|---|---|",
    ]
    lines += [f"| {_label(k)} | {_fmt_n(v)} |" for k, v in toy["crossing_n"].items()]
    lines += [
        "",
        "Within one frame of the paper's model: "
        + ", ".join(f"{_label(k)} {'yes' if v['within_one_frame'] else 'no'}" for k, v in acc["toy"].items()),
        "",
    ]
    for cond, data in metrics["conditions"].items():
        thresholds = list(next(iter(data["filters"].values()))["thresholds"])
        sz = data["sizes"]
        lines += [
            f"## {_title(cond).capitalize()}",
            "",
            f"{sz['calibration_sequences_per_class']} labelled calibration sequences per class, "
            f"{sz['held_out_sequences']} held-out sequences of {sz['frames']} frames; per-frame classifier "
            f"accuracy {data['frame_accuracy']:.3f}; every number ± its standard error. Fitted tempers: "
            + ", ".join(f"{_label(k)} {v:g}" for k, v in data["temper"].items())
            + ".",
            "",
            *condition_table(data, thresholds),
            "",
        ]
        a = acc.get(cond, {})
        if a:
            lines += [
                "Checks (best model by held-out log score, "
                + f"{_label(a['best_model'])}): "
                + ", ".join(
                    f"`{k}` = {v:.3f}" if isinstance(v, float) else f"`{k}` = {v}"
                    for k, v in a.items()
                    if k != "best_model" and not isinstance(v, dict)
                ),
                "",
            ]
        peer = a.get("default_vs_calibrated")
        if peer:
            lines += [
                f"The default (sequence model, stopping at {peer['stop']:g} for the promise 0.95) against the "
                f"calibrated peer: right when it emits {peer['emitted_accuracy']:.3f} ± {peer['emitted_stderr']:.3f} "
                f"(peer {peer['peer_emitted_accuracy']:.3f}), {peer['mean_frames']:.2f} frames against "
                f"{peer['peer_mean_frames']:.2f} ({peer['frames_over_peer']:.2f}x), timeouts "
                f"{peer['timeout_rate']:.3f}: honest {peer['honest']}, at most 1.5x the peer's frames "
                f"{peer['frames_at_most_1.5x_peer']}, timeouts at most 10 % {peer['timeouts_at_most_0.1']}.",
                "",
            ]
        honest = metrics.get("honesty", {}).get(cond)
        if honest:
            lines += [
                "Honest (emitted labels right at least t - 0.03) at t = "
                + ", ".join(thresholds)
                + ": "
                + "; ".join(
                    f"{_label(k)} " + "/".join("yes" if v[t] else "no" for t in thresholds) for k, v in honest.items()
                ),
                "",
            ]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"
