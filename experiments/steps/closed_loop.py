"""Planned against executed: policies run with the actual filter on held-out recorded streams.

A policy is planned on a macro-observation model (a table of ``P(label, frames | true class)``,
from recorded streams or from the fitted generative model) and scored there: its *planned* value.
:func:`execute` runs the same saved controller in the same domain, but every "infer" MA draws a
fresh recorded stream of the true object's class from a bank the planner never saw and runs that
variant's process (filter, threshold, frame budget) on it (:class:`hbni_pyro.StreamReplay`): its
*executed* value. Their gap, in standard errors, says how honest the planning model is.

Two kinds of standard error enter that gap. Rollouts: each value is a Monte Carlo mean. Streams:
a table tabulated on 16 recorded sequences per class, or a bank of 64, is itself a sample of
imaging conditions (a table's sequence ``i`` of every class shares its pose, light and background;
the bank's classes each have their own), so a planned or executed value carries the luck of its
sequences too. :func:`stream_stderr` measures that part by bootstrap: if the planning model is
honest, the table's recorded sequences and the bank's are draws from one population, so (as in a
pooled two-sample test) each value's stream standard error is the spread of that policy's value
over tables or banks of the same size drawn from the pooled sequences (a table of some sequences
and a replay of them give the same law of ``(label, frames)``, so both are replays of the process's
results on the pooled streams, computed once). The honesty verdict uses the gap in all four standard
errors together. A generative table is simulated (1000 streams per class by default): its own
simulation error is neglected.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from statistics import NormalDist
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import torch
from hydra.utils import instantiate

import hbni_pyro
from decpomdp import JointController
from experiments.reports import figures
from experiments.reports.scores import beats, ratio
from experiments.schemas.mission_study import PLANNING_MODELS, BootstrapBlock
from experiments.steps import honesty
from experiments.steps.planning import delivery_rates, score
from hbni_pyro import binomial_stderr
from hbni_infra.streams import stream_seed, torch_stream


def other_model(planning_model: str) -> str:
    """The planning model other than ``planning_model`` (HBNI's comparison entry plans on it)."""
    return PLANNING_MODELS[1 - PLANNING_MODELS.index(planning_model)]


def gap(planned: dict[str, float], executed: dict[str, float], *extra: float) -> float:
    """``(executed - planned) / sqrt(se_p^2 + se_e^2 + sum extra^2)``: the departure in standard errors."""
    se = (planned["stderr"] ** 2 + executed["stderr"] ** 2 + sum(e**2 for e in extra)) ** 0.5
    return (executed["value"] - planned["value"]) / se if se > 0 else float("nan")


def as_streams(outputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Outputs ``(C, S, F, C)`` (sequences per class) as streams ``(C * S, F, C)`` float64 and true classes ``(C * S,)``."""
    C, S = outputs.shape[:2]
    return outputs.reshape(C * S, *outputs.shape[2:]).double(), torch.arange(C).repeat_interleave(S)


def sequence_streams(sequences: torch.Tensor, num_classes: int, per_class: int) -> torch.Tensor:
    """Stream indices (in :func:`as_streams` order) of sequences ``sequences (K,)`` of every class: ``(C * K,)``."""
    return (torch.arange(num_classes)[:, None] * per_class + sequences).reshape(-1)


def resampled(
    replay: hbni_pyro.StreamReplay, num_classes: int, per_class: int, sequences: torch.Tensor
) -> hbni_pyro.StreamReplay:
    """``replay`` restricted to sequences ``sequences`` of every class (streams in :func:`as_streams` order)."""
    return replay.subset(sequence_streams(sequences, num_classes, per_class))


def stream_stderr(
    controller: JointController,
    perception_of: Callable[[torch.Tensor], Any],
    pool: int,
    size: int,
    domain: Any,
    boot: BootstrapBlock,
    seed: int,
) -> float:
    """Standard error of a policy's value from the finite set of ``size`` recorded sequences behind its perception.

    Each replicate draws ``size`` of ``pool`` sequence indices with replacement (all classes' sequence ``i``
    together: where they share imaging conditions, their outcomes go together), builds
    ``perception_of(indices)`` (a table or a replay) and scores the policy on ``boot.rollouts`` fresh rollouts.
    The replicates' variance minus their mean rollout variance is the streams' share (floored at 0). That difference is only as good as the
    replicates' variance estimate (relative s.e. ``sqrt(2 / (replicates - 1))`` of the streams' plus the
    rollouts' share): give each replicate enough rollouts that their noise does not swamp the streams'.
    """
    g = torch_stream(seed, "resample")
    values, variances = [], []
    for b in range(boot.replicates):
        idx = torch.randint(pool, (size,), generator=g)
        entry = score(
            instantiate(domain, perception=perception_of(idx)),
            controller,
            boot.rollouts,
            stream_seed(seed, "replicate", b),
        )
        values.append(entry["value"])
        variances.append(entry["stderr"] ** 2)
    return float(max(np.var(values, ddof=1) - np.mean(variances), 0.0) ** 0.5)


def execute(controller: JointController, perception: Any, domain: Any, rollouts: int, seed: int) -> dict[str, Any]:
    """The score of ``controller`` in the domain whose "infer" MA is answered by ``perception``.

    ``perception``: a :class:`hbni_pyro.StreamReplay` (closed loop) or ``None`` (perfect perception). The
    entry's ``oracle`` is the same score on the batched torch simulator (the compiled engine's oracle): its
    gap in standard errors says the executed value means the same on both.
    """
    env = instantiate(domain, perception=perception)
    entry = score(env, controller, rollouts, seed)
    entry["mean_inference_frames"] = delivery_rates(entry)["mean_inference_frames"]
    oracle = score(env, controller, rollouts, seed, backend="torch")  # the same rollouts' law on the torch oracle
    entry["oracle"] = {"value": oracle["value"], "stderr": oracle["stderr"], "gap_in_stderr": gap(oracle, entry)}
    return entry


def summarise(
    entry: dict[str, Any],
    executed: dict[str, Any],
    replay: hbni_pyro.StreamReplay | None,
    planned_streams: float = 0.0,
    executed_streams: float = 0.0,
) -> dict[str, Any]:
    """The closed-loop part of a variant's metrics: executed score, gaps, and the process on the streams it ran on.

    ``planned_streams``/``executed_streams``: the stream standard errors of the two values (:func:`stream_stderr`).
    """
    out = {
        "value": executed["value"],
        "stderr": executed["stderr"],
        "gap_in_stderr": gap(entry, executed),
        "planned_stream_stderr": planned_streams,
        "stream_stderr": executed_streams,
        "gap_in_total_stderr": gap(entry, executed, planned_streams, executed_streams),
        "delivered_per_rollout": executed["delivered_per_rollout"],
        "wrong_per_rollout": executed["wrong_per_rollout"],
        "mean_inference_frames": executed["mean_inference_frames"],
        "oracle": executed["oracle"],
    }
    if replay is not None:
        right = (replay.results.label == replay.true_class).double()
        out["bank_accuracy"] = [float(right[replay.true_class == c].mean()) for c in range(replay.num_classes)]
        frames = replay.results.frames_used.double()
        out["bank_mean_frames"] = [float(frames[replay.true_class == c].mean()) for c in range(replay.num_classes)]
    return out


def held_out_summary(replay: hbni_pyro.StreamReplay, threshold: float) -> dict[str, Any]:
    """A variant's process on every held-out stream it ran on in closed loop (characterisation and bank sequences,
    and any rendered on demand): the promised ``threshold``, the confidence it ``stop``s at, the share of its
    emitted labels that are right with its binomial s.e., the share of all its labels that are right (a timeout's
    too: the label at the budget), its mean frames (a timeout counting the budget) with their s.e., and its timeout
    rate."""
    r = replay.results
    emitted, right = ~r.timed_out, r.label == replay.true_class
    n, frames = int(emitted.sum()), r.frames_used.double()
    accuracy = float(right[emitted].double().mean()) if n else float("nan")
    return {
        "threshold": threshold,
        "stop": replay.process.threshold,
        "streams": len(right),
        "emitted_accuracy": accuracy,
        "emitted_stderr": binomial_stderr(accuracy, n),
        "accuracy": float(right.double().mean()),
        "mean_frames": float(frames.mean()),
        "frames_stderr": float(frames.std() / math.sqrt(len(frames))),
        "timeout_rate": float(r.timed_out.double().mean()),
    }


def acceptance(results: dict[str, dict]) -> dict[str, Any]:
    """The closed-loop checks on executed values: HBNI against perfect perception, the calibrated peer, SSBF and
    max-of-mean."""
    if "hbni" not in results or "executed" not in results["hbni"]:
        return {}
    h = results["hbni"]["executed"]
    out: dict[str, Any] = {
        "hbni_executed_over_perfect": ratio(h["value"], results["perfect"]["executed"]["value"]),
        "hbni_executed_over_planned": ratio(h["value"], results["hbni"]["value"]),
    }
    if "distribution_check" in h:
        out["hbni_distribution_check_passed"] = h["distribution_check"]["passed"]
    if "calibrated" in results:
        peer = results["calibrated"]
        out["hbni_executed_over_calibrated"] = ratio(h["value"], peer["executed"]["value"])
        out["hbni_executed_at_least_calibrated"] = h["value"] >= peer["executed"]["value"]
        if "held_out_process" in results["hbni"] and "held_out_process" in peer:
            a, b = results["hbni"]["held_out_process"], peer["held_out_process"]
            out["hbni_honest_on_held_out"] = a["emitted_accuracy"] + a["emitted_stderr"] >= a["threshold"]
            out["hbni_frames_over_calibrated"] = ratio(a["mean_frames"], b["mean_frames"])
            out["hbni_frames_at_most_1.5x_calibrated"] = a["mean_frames"] <= 1.5 * b["mean_frames"]
            out["hbni_timeouts_at_most_0.1"] = a["timeout_rate"] <= 0.10
    out["hbni_executed_at_least_98pct_perfect"] = h["value"] >= 0.98 * results["perfect"]["executed"]["value"]
    for other in ("calibrated", "ssbf", "max_of_mean"):
        if other in results:
            o = results[other]["executed"]
            out[f"hbni_executed_beats_{other}_outside_stderr"] = beats(h, o)
            out[f"hbni_minus_{other}_executed_in_stderr"] = ratio(
                h["value"] - o["value"], (h["stderr"] ** 2 + o["stderr"] ** 2) ** 0.5
            )
    return out


def report_lines(
    results: dict[str, dict], labels: dict[str, str], planning: dict[str, str], bank: dict[str, Any]
) -> list[str]:
    """Markdown: planned vs executed per variant, and which planning model the gaps call honest."""
    rows = [
        "| policy | planned on | planned value (± rollout s.e.; streams s.e.) | executed value (± rollout s.e.; "
        "streams s.e.) | gap (rollout s.e.) | gap (all s.e.) | executed wrong / run | executed frames / inference "
        "| held-out accuracy | held-out mean frames | executed on the torch oracle (gap) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        e = r["executed"]
        acc = f"{np.mean(e['bank_accuracy']):.3f}" if "bank_accuracy" in e else "1"
        frames = f"{np.mean(e['bank_mean_frames']):.1f}" if "bank_mean_frames" in e else "-"
        rows.append(
            f"| {labels.get(name, name)} | {planning.get(name, 'exact')} | {r['value']:.3f} ± {r['stderr']:.3f}; "
            f"{e['planned_stream_stderr']:.3f} | {e['value']:.3f} ± {e['stderr']:.3f}; {e['stream_stderr']:.3f} | "
            f"{e['gap_in_stderr']:+.1f} | {e['gap_in_total_stderr']:+.1f} | {e['wrong_per_rollout']:.2f} | "
            f"{e['mean_inference_frames']:.1f} | {acc} | {frames} | {e['oracle']['value']:.3f} ± "
            f"{e['oracle']['stderr']:.3f} ({e['oracle']['gap_in_stderr']:+.1f}) |"
        )
    source = "loaded from the cache" if bank["cached"] else "rendered and classified for this run"
    lines = [
        "## Closed loop: planned against executed",
        "",
        f'Every "infer" MA of an executed rollout draws a held-out mission sequence of the true class '
        f"({bank['frames']} frames) and runs that variant's filter and threshold on it: a policy planned on a "
        f"simulated table draws from {bank['held_out_sequences_per_class'] + bank['sequences_per_class']} per "
        f"class (the {bank['held_out_sequences_per_class']} characterisation sequences and the bank's "
        f"{bank['sequences_per_class']}, none of which it saw), one planned on an empirical table from the bank's "
        f"only (seed {bank['seed']}, never used to fit or tabulate; {source}: `{bank['path']}`). The rollout gap is "
        "(executed - planned) / sqrt(se_planned^2 + se_executed^2) with rollout standard errors; the full gap "
        "adds both values' stream standard errors (bootstrap over the sequences of the table and of the bank; "
        "0 for a simulated table). The last column runs the same controllers on the batched torch simulator, the "
        "compiled engine's oracle, with the gap in standard errors.",
        "",
        *rows,
        "",
    ]
    for name, r in results.items():
        more = r["executed"].get("on_demand")
        if more:
            lines.append(
                f"- {labels.get(name, name)}: its value test had less than {honesty.TARGET_POWER:.0%} power on those "
                f"sequences, so its process also ran on the bank's next {more['sequences_per_class']} sequences per "
                f"class, each rendered a block of frames at a time only as far as the process read it (mean "
                f"{more['mean_frames_rendered']:.1f} of {bank['frames']} frames): "
                f"{r['executed']['sequences_per_class']} held-out sequences per class in all."
            )
    return lines + ([""] if lines[-1] else []) + honesty_lines(results, planning) + [""]


def honesty_lines(results: dict[str, dict], planning: dict[str, str]) -> list[str]:
    """Which planning model predicts its policies' executed values (no policy planned on it fails the value test,
    :func:`experiments.steps.honesty.value_test`), with the gaps and, per policy, what its table predicted against
    what the bank gave (accuracy, frames)."""
    out = []
    for model in PLANNING_MODELS:
        names = [name for name in results if planning.get(name) == model]
        if not names:
            continue
        gaps = {name: results[name]["executed"]["gap_in_total_stderr"] for name in names}
        honest = all(honesty.shortfall_p(results[n], results[n]["executed"]) >= honesty.VALUE_ALPHA for n in names)
        listed = ", ".join(f"{n} {g:+.1f}" for n, g in gaps.items())
        out.append(
            f"- The **{model}** planning model is **{'honest' if honest else 'not honest'}** here: full gaps "
            f"{listed} s.e. (honest: no executed value falls short of its plan at level {honesty.VALUE_ALPHA:g}, "
            f"every gap >= {NormalDist().inv_cdf(honesty.VALUE_ALPHA):.2f})."
        )
        for name in names:
            r, e = results[name], results[name]["executed"]
            if "macro_accuracy" in r and "bank_accuracy" in e:
                out.append(
                    f"  - {name}: its table says accuracy {np.mean(r['macro_accuracy']):.3f} after "
                    f"{np.mean(r['macro_mean_frames']):.1f} frames; on its held-out streams the process gets "
                    f"{np.mean(e['bank_accuracy']):.3f} after {np.mean(e['bank_mean_frames']):.1f}."
                )
    return out


def figure(results: dict[str, dict], labels: dict[str, str]) -> plt.Figure:
    """Planned and executed value (± s.e.) of every policy side by side."""
    names = list(results)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(7.5, 1.6 * len(names)), 4.2))
    colors = [figures.color(n) for n in names]  # each policy's colour, as in values.png; planned is the light shade
    ax.bar(
        x - 0.2,
        [results[n]["value"] for n in names],
        0.4,
        yerr=[results[n]["stderr"] for n in names],
        capsize=3,
        label="planned, on its planning model (light)",
        color=colors,
        alpha=0.4,
    )
    ax.bar(
        x + 0.2,
        [results[n]["executed"]["value"] for n in names],
        0.4,
        yerr=[results[n]["executed"]["stderr"] for n in names],
        capsize=3,
        label="executed in closed loop (solid)",
        color=colors,
    )
    for i, n in enumerate(names):
        e = results[n]["executed"]
        top = max(results[n]["value"], e["value"])
        ax.text(
            i, top * 1.02, f"{e['gap_in_stderr']:+.1f} / {e['gap_in_total_stderr']:+.1f} s.e.", ha="center", fontsize=8
        )
    ax.set_xticks(x, [labels.get(n, n) for n in names], fontsize=figures.TICK_SIZE)
    ax.set_ylabel("discounted return (mean ± s.e.)", fontsize=figures.LABEL_SIZE)
    ax.set_title("Planned vs executed value (gap in rollout / all standard errors)", fontsize=figures.TITLE_SIZE)
    ax.set_ylim(0, 1.15 * max(max(r["value"], r["executed"]["value"]) for r in results.values()))
    ax.legend(fontsize=figures.TICK_SIZE, loc="lower right")
    fig.tight_layout()
    return fig
