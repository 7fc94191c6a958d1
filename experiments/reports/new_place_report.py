"""The new-place study's acceptance checks, figures and ``report.md`` (:mod:`experiments.studies.new_place`)."""

from __future__ import annotations

import math
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from experiments.reports import figures
from experiments.reports.scores import ratio

FEW_LABELS = 2
"""Up to this many labelled sequences per class HBNI adapted must beat the peer outright; with more, match it."""
FAMILIES = {
    "hbni": ("HBNI adapted (K labelled + unlabelled)", "tab:blue", "o-"),
    "calibrated": ("calibrated peer (K new labels; old place's at K = 0)", "tab:red", "s-"),
    "hbni_old": ("HBNI from the old place", "tab:gray", "--"),
}


def acceptance(results: dict[str, dict], labelled: tuple[int, ...], threshold: float) -> dict[str, dict[str, Any]]:
    """Per ``K``: HBNI adapted against the peer and HBNI from the old place, executed in closed loop.

    With at most :data:`FEW_LABELS` labels per class it must execute above the peer by more than 2 standard errors
    of the difference and above HBNI from the old place, emit labels right at least ``threshold`` of the time
    (within one binomial s.e.) and time out on at most 10 % of sequences; with more, execute at least as well as the
    peer (within one s.e.), in at most 1.5 times its frames, and be honest. Standard errors count rollouts and the
    finite bank of held-out sequences."""
    out = {}
    old = results["hbni_old"]["executed"]
    for K in labelled:
        h, p = results[f"hbni_K{K}"], results[f"calibrated_K{K}"]
        eh, ep, proc, peer = h["executed"], p["executed"], h["held_out_process"], p["held_out_process"]
        diff = eh["value"] - ep["value"]
        se = math.hypot(eh["total_stderr"], ep["total_stderr"])
        cell = {
            "executed": eh["value"],
            "peer_executed": ep["value"],
            "minus_peer_in_stderr": ratio(diff, se),
            "old_executed": old["value"],
            "minus_old_in_stderr": ratio(
                eh["value"] - old["value"], math.hypot(eh["total_stderr"], old["total_stderr"])
            ),
            "emitted_accuracy": proc["emitted_accuracy"],
            "emitted_stderr": proc["emitted_stderr"],
            "honest": proc["emitted_accuracy"] + proc["emitted_stderr"] >= threshold,
            "timeout_rate": proc["timeout_rate"],
            "frames": proc["mean_frames"],
            "peer_frames": peer["mean_frames"],
            "frames_over_peer": ratio(proc["mean_frames"], peer["mean_frames"]),
        }
        if K <= FEW_LABELS:
            cell["checks"] = {
                "above_peer_by_2_stderr": diff > 2 * se,
                "above_old_place_hbni": eh["value"] > old["value"],
                "honest": cell["honest"],
                "timeouts_at_most_0.1": proc["timeout_rate"] <= 0.10,
            }
        else:
            cell["checks"] = {
                "at_least_peer_within_1_stderr": diff >= -se,
                "frames_at_most_1.5x_peer": cell["frames_over_peer"] <= 1.5,
                "honest": cell["honest"],
            }
        cell["met"] = all(cell["checks"].values())
        out[f"K{K}"] = cell
    return out


def _series(entries: dict[str, dict], family: str, labelled: tuple[int, ...], get) -> tuple[list, list]:
    names = [f"{family}_K{K}" for K in labelled]
    pairs = [get(entries[n]) for n in names]
    return [v for v, _ in pairs], [e for _, e in pairs]


def figure(results: dict[str, dict], labelled: tuple[int, ...], place: str) -> plt.Figure:
    """Executed value, right-when-emits and frames against ``K`` for every variant, with standard errors."""
    panels = (
        ("executed value (± s.e.)", lambda r: (r["executed"]["value"], r["executed"]["total_stderr"])),
        ("emitted labels right (± s.e.)", _emitted),
        ("frames per inference (± s.e.)", _frames),
    )
    perfect = results["perfect"]["executed"]["value"]
    return _against_k(
        results, labelled, panels, {0: ("perfect perception", perfect)}, "K labelled sequences per class", place
    )


def process_figure(entries: dict[str, dict], labelled: tuple[int, ...], place: str) -> plt.Figure:
    """Right, right-when-emits and frames against ``K`` of every filter's process on held-out streams."""
    panels = (
        ("labels right, timeouts' too (± s.e.)", _right),
        ("emitted labels right (± s.e.)", _emitted),
        ("frames per inference (± s.e.)", _frames),
    )
    return _against_k(entries, labelled, panels, {}, "each filter on held-out sequences", place)


def _against_k(
    entries: dict[str, dict],
    labelled: tuple[int, ...],
    panels: tuple,
    references: dict[int, tuple[str, float]],
    what: str,
    place: str,
) -> plt.Figure:
    """One panel per ``(title, get)`` of ``panels``: each family's ``get(entry) -> (value, s.e.)`` against ``K``,
    HBNI from the old place as a band, the promise on the emitted-labels panel and ``references`` (panel index ->
    (label, value)) as dotted lines."""
    fig, axes = plt.subplots(1, len(panels), figsize=(14.5, 4.3))
    x = np.arange(len(labelled))
    promised = entries["hbni_old"]["held_out_process"]["threshold"]
    for i, (ax, (title, get)) in enumerate(zip(axes, panels)):
        for family in ("hbni", "calibrated"):
            label, colour, style = FAMILIES[family]
            values, errors = _series(entries, family, labelled, get)
            ax.errorbar(x, values, yerr=errors, fmt=style, color=colour, capsize=3, label=label)
        label, colour, style = FAMILIES["hbni_old"]
        value, error = get(entries["hbni_old"])
        ax.axhline(value, color=colour, linestyle=style, label=label)
        ax.axhspan(value - error, value + error, color=colour, alpha=0.15)
        if i in references:
            ax.axhline(references[i][1], color="black", linestyle=":", label=references[i][0])
        if title.startswith("emitted"):
            ax.axhline(promised, color=figures.THRESHOLD_COLOR, linestyle="-.", label="promised")
        ax.set_xticks(x, [str(K) for K in labelled], fontsize=figures.TICK_SIZE)
        ax.set_xlabel("K: labelled new-place sequences per class", fontsize=figures.LABEL_SIZE)
        ax.set_title(title, fontsize=figures.LABEL_SIZE)
        ax.grid(alpha=0.3)
    handles = {label: h for ax in axes for h, label in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), fontsize=8, loc="lower center", ncol=len(handles))
    fig.suptitle(f"A new place ({place}): {what}", fontsize=figures.TITLE_SIZE)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig


def _emitted(entry: dict) -> tuple[float, float]:
    p = entry["held_out_process"]
    return p["emitted_accuracy"], p["emitted_stderr"]


def _frames(entry: dict) -> tuple[float, float]:
    p = entry["held_out_process"]
    return p["mean_frames"], p["frames_stderr"]


def _right(entry: dict) -> tuple[float, float]:
    p = entry["held_out_process"]
    return p["accuracy"], math.sqrt(p["accuracy"] * (1 - p["accuracy"]) / p["streams"])


def _process_row(name: str, entry: dict) -> str:
    p = entry["held_out_process"]
    return (
        f"{p['stop']:.3f} | {p['accuracy']:.3f} | {p['emitted_accuracy']:.3f} ± {p['emitted_stderr']:.3f} | "
        f"{p['timeout_rate']:.3f} | {p['mean_frames']:.2f} ± {p['frames_stderr']:.2f}"
    )


def _label(name: str) -> str:
    if name == "hbni_old":
        return "HBNI from the old place"
    family, K = name.rsplit("_K", 1)
    return f"{'HBNI adapted' if family == 'hbni' else 'calibrated peer'}, K = {K}"


def report(metrics: dict[str, Any], figure_files: list[str]) -> str:
    """``report.md`` of a run."""
    results, acc = metrics["variants"], metrics["acceptance"]
    unl = metrics["unlabelled"]
    lines = [
        "# A new place, few or no labels",
        "",
        "The classifier and the old place's labels are the mission's; the mission runs at a new place (dusk: "
        f"imaging `{_conditions(metrics['conditions']['new'])}`). Classifier frame accuracy: old place "
        f"{metrics['frame_accuracy']['old']:.3f}, new place {metrics['frame_accuracy']['new']:.3f}. HBNI is adapted on K "
        f"labelled sequences per class and {unl['streams']} unlabelled streams (class mix {unl['mix']}).",
        "",
        *[f"![{f}]({f})" for f in figure_files],
        "",
        "## Closed loop at the new place",
        "",
        "| policy | stop | planned value | executed value (± rollout s.e.; streams s.e.) | right | right when it emits "
        "| timeouts | frames |",
        "|---|---|---|---|---|---|---|---|",
    ]
    perfect = results["perfect"]["executed"]
    lines.append(
        f"| perfect perception | - | {results['perfect']['value']:.3f} | {perfect['value']:.3f} ± "
        f"{perfect['stderr']:.3f} | 1 | 1 | 0 | - |"
    )
    for name, r in results.items():
        if name == "perfect":
            continue
        e = r["executed"]
        proc = _process_row(name, r).split(" | ", 1)
        lines.append(
            f"| {_label(name)} | {proc[0]} | {r['value']:.3f} | {e['value']:.3f} ± {e['stderr']:.3f}; "
            f"{e['stream_stderr']:.3f} | {proc[1]} |"
        )
    lines += ["", "## Acceptance", ""]
    for key, cell in acc.items():
        checks = ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in cell["checks"].items())
        lines.append(
            f"- {key}: **{'met' if cell['met'] else 'missed'}** ({checks}): executed {cell['executed']:.3f} against "
            f"the peer's {cell['peer_executed']:.3f} ({cell['minus_peer_in_stderr']:+.1f} s.e.) and HBNI from the old "
            f"place's {cell['old_executed']:.3f} ({cell['minus_old_in_stderr']:+.1f} s.e.); emitted labels right "
            f"{cell['emitted_accuracy']:.3f} ± {cell['emitted_stderr']:.3f}; timeouts {cell['timeout_rate']:.3f}; "
            f"{cell['frames']:.2f} frames, {cell['frames_over_peer']:.2f} times the peer's."
        )
    lines += [
        "",
        "Unlabelled streams' classes recovered by the adapted fits: "
        + ", ".join(f"{n} {v:.3f}" for n, v in unl["classes_recovered"].items())
        + ".",
    ]
    photos = metrics.get("photos")
    if photos:
        lines += [
            "",
            "## Photographs, a darker camera",
            "",
            f"Frame accuracy: old camera {photos['frame_accuracy']['old']:.3f}, new camera "
            f"{photos['frame_accuracy']['new']:.3f}.",
            "",
            "| filter | stop | right | right when it emits | timeouts | frames |",
            "|---|---|---|---|---|---|",
            *[f"| {_label(n)} | {_process_row(n, e)} |" for n, e in photos["variants"].items()],
        ]
    return "\n".join(lines) + "\n"


def _conditions(conditions: dict[str, Any]) -> str:
    keys = ("gain", "noise", "cast", "blur", "scale")
    return ", ".join(f"{k} {conditions[k]}" for k in keys)
