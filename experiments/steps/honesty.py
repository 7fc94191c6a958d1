"""Is a planning model honest? Its macro-observation law against the process on the held-out bank.

A policy is planned on a table of ``P(label, frames | true class)``. Two tests judge that table (reported as the
entry's ``distribution_check`` and ``value_test``):

- :func:`distribution_test`, per class: the table's accuracy and mean frames against what the
  process does on the bank's streams of that class, each by a parametric-bootstrap test of "one
  law behind both". A table is a sample of ``table_streams`` streams per class (held-out streams for
  an empirical table, simulated ones for a generative table), so the test is two-sample under the
  pooled law: a table that saw no error in a thousand streams does not make one error on the bank
  impossible (``table_streams=None`` takes the table as exact). A Wilson interval on the bank's
  accuracy and a bootstrap interval on its mean frames go with the p-values. A class passes when both
  p-values reach ``alpha`` over the number of tests (Bonferroni).
- :func:`value_test`: does the policy's executed value fall short of its planned value? A one-sided
  test at level :data:`VALUE_ALPHA` on the full gap (rollout and stream standard errors of both
  values): a plan that promises too much fails it. It reports its p-value, its power against a given
  relative shortfall and the bank size that would give the target power (stream standard errors
  scale as ``1 / sqrt(size)``).
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Any

import matplotlib.pyplot as plt
import torch

import hbni_pyro
from experiments.reports import figures
from hbni_pyro import stream_reliability
from hbni_infra.stats import wilson_interval
from hbni_infra.streams import torch_stream

ALPHA = 0.05
"""Family-wise level of the distribution test (split over its classes and its two statistics)."""

VALUE_ALPHA = 0.05
"""Level of the value test: a policy fails when ``(executed - planned) / full s.e.`` is below the
``VALUE_ALPHA`` quantile of the standard normal (-1.645)."""

SHORTFALL = 0.03
"""The relative shortfall of the executed value below the planned one whose detection power is reported."""

TARGET_POWER = 0.8
"""The power against :data:`SHORTFALL` the reported bank size is for."""


def _proportions(n: int, p: float, replicates: int, g: torch.Generator) -> torch.Tensor:
    """``(replicates,)`` shares of successes in ``n`` Bernoulli(``p``) trials."""
    return (
        torch.binomial(
            torch.full((replicates,), float(n), dtype=torch.float64),
            torch.full((replicates,), p, dtype=torch.float64),
            generator=g,
        )
        / n
    )


def _pmf_means(pmf: torch.Tensor, n: int, replicates: int, g: torch.Generator) -> torch.Tensor:
    """``(replicates,)`` means of ``n`` draws (values 1, 2, ...) from ``pmf (F,)``."""
    draws = torch.multinomial(pmf.expand(replicates, -1), n, replacement=True, generator=g) + 1
    return draws.double().mean(1)


def _two_sided(null: torch.Tensor, observed: float) -> float:
    """Share of null statistics at least as far out as ``observed`` (with the +1 correction)."""
    return float(((null >= observed - 1e-12).sum() + 1) / (null.numel() + 1))


def class_test(
    predicted_pmf: torch.Tensor,
    predicted_accuracy: float,
    right: torch.Tensor,
    frames: torch.Tensor,
    table_streams: int | None,
    replicates: int,
    g: torch.Generator,
) -> dict[str, Any]:
    """One class: the table's frames pmf ``(F,)`` and accuracy against the bank's ``right (n,)`` and
    ``frames (n,)`` (1-based); ``table_streams`` the table's sample size, ``None`` for an exact table."""
    n = right.numel()
    k, mean_frames = int(right.sum()), float(frames.double().mean())
    bank_pmf = torch.bincount(frames - 1, minlength=predicted_pmf.numel()).double() / n
    pred_frames = float(predicted_pmf @ torch.arange(1, predicted_pmf.numel() + 1, dtype=torch.float64))
    if table_streams is None:
        p0, pmf0 = predicted_accuracy, predicted_pmf
        acc_null = (_proportions(n, p0, replicates, g) - p0).abs()
        frames_null = (_pmf_means(pmf0, n, replicates, g) - pred_frames).abs()
    else:
        m = table_streams
        p0 = (predicted_accuracy * m + k) / (m + n)
        pmf0 = (predicted_pmf * m + bank_pmf * n) / (m + n)
        acc_null = (_proportions(n, p0, replicates, g) - _proportions(m, p0, replicates, g)).abs()
        frames_null = (_pmf_means(pmf0, n, replicates, g) - _pmf_means(pmf0, m, replicates, g)).abs()
    boot = torch.randint(n, (replicates, n), generator=g)
    frame_means = frames.double()[boot].mean(1)
    return {
        "predicted_accuracy": predicted_accuracy,
        "bank_accuracy": k / n,
        "accuracy_interval": wilson_interval(k, n),
        "accuracy_p": _two_sided(acc_null, abs(k / n - predicted_accuracy)),
        "predicted_frames": pred_frames,
        "bank_frames": mean_frames,
        "frames_interval": tuple(
            torch.quantile(frame_means, torch.tensor([0.025, 0.975], dtype=torch.float64)).tolist()
        ),
        "frames_p": _two_sided(frames_null, abs(mean_frames - pred_frames)),
        "bank_streams": n,
    }


def distribution_test(
    model: hbni_pyro.MacroObservationModel,
    replay: hbni_pyro.StreamReplay,
    table_streams: int | None,
    seed: int,
    alpha: float = ALPHA,
    replicates: int = 4000,
) -> dict[str, Any]:
    """Per class, the table ``model`` against the process's results on the bank (``replay``).

    Returns ``{"classes": [per-class dict], "alpha_per_test", "passed"}``; each class dict holds the
    predicted and bank accuracy (Wilson interval) and mean frames (bootstrap interval), both p-values
    and ``passed``.
    """
    if replay.num_classes != model.num_classes:
        raise ValueError(f"replay: expected {model.num_classes} classes as in the table, got {replay.num_classes}")
    if replay.results.frames_used.max() > model.max_frames:
        raise ValueError(f"replay: its streams run past the table's {model.max_frames} frames")
    g = torch_stream(seed, "distribution_check")
    per_test = alpha / (2 * model.num_classes)
    classes = []
    for c in range(model.num_classes):
        mine = replay.true_class == c
        entry = class_test(
            model.frames_pmf[c],
            float(model.accuracy[c]),
            replay.results.label[mine] == c,
            replay.results.frames_used[mine],
            table_streams,
            replicates,
            g,
        )
        entry["passed"] = entry["accuracy_p"] >= per_test and entry["frames_p"] >= per_test
        classes.append(entry)
    return {"classes": classes, "alpha_per_test": per_test, "passed": all(e["passed"] for e in classes)}


def shortfall_p(planned: dict[str, float], executed: dict[str, float]) -> float:
    """One-sided p-value of "the executed value is at least the planned one": the normal tail at the full gap
    ``executed["gap_in_total_stderr"]``; without any error (no gap in standard errors) 1 or 0, exactly."""
    gap = executed["gap_in_total_stderr"]
    if math.isnan(gap):
        return 1.0 if executed["value"] >= planned["value"] else 0.0
    return NormalDist().cdf(gap)


def value_test(
    planned: dict[str, float],
    executed: dict[str, float],
    bank_size: int,
    shortfall: float = SHORTFALL,
    alpha: float = VALUE_ALPHA,
    target: float = TARGET_POWER,
) -> dict[str, float | bool]:
    """The value test of one policy: its p-value and verdict, its power against an executed value ``shortfall``
    (relative) below the planned one, and the held-out sequences per class that would give ``target`` power.

    ``planned``: ``{"value", "stderr"}``; ``executed``: the closed-loop entry (``value``, ``stderr``,
    ``stream_stderr``, ``planned_stream_stderr``, ``gap_in_total_stderr``). The bank's stream standard error is scaled as
    ``sqrt(bank_size / size)``; the other errors stay (the rollouts' and those of the table's own sequences).
    """
    fixed = planned["stderr"] ** 2 + executed["stderr"] ** 2 + executed["planned_stream_stderr"] ** 2
    bank = executed["stream_stderr"] ** 2
    delta = shortfall * abs(planned["value"])
    se = math.sqrt(fixed + bank)
    z = NormalDist()
    p = shortfall_p(planned, executed)
    out = {"p_value": p, "passed": p >= alpha, "alpha": alpha, "shortfall": shortfall, "target_power": target}
    if se == 0:  # no error at all: any shortfall shows
        return {
            **out,
            "power": 1.0 if delta > 0 else 0.0,
            "total_stderr": 0.0,
            "sequences_for_target": float(bank_size),
        }
    critical = z.inv_cdf(1 - alpha)
    power = z.cdf(delta / se - critical)
    room = (delta / (critical + z.inv_cdf(target))) ** 2 - fixed
    if bank == 0:
        size = float(bank_size) if room >= 0 else math.inf
    else:
        size = float(math.ceil(bank_size * bank / room)) if room > 0 else math.inf
    return {**out, "power": power, "total_stderr": se, "sequences_for_target": size}


def reliability_figure(
    processes: dict[str, hbni_pyro.MacroObservationProcess],
    streams: torch.Tensor,
    truth: torch.Tensor,
    labels: dict[str, str],
    threshold: float,
) -> plt.Figure:
    """Reliability of every process's filter on the bank: after every prefix of every stream, the top
    posterior probability against how often the top class is right (point size: share of prefixes)."""
    fig, ax = plt.subplots(figsize=(6.0, 5.6))
    low = 1.0 / next(iter(processes.values())).num_classes
    ax.plot([low, 1], [low, 1], color="0.6", lw=1, ls="--", label="calibrated")
    for name, process in processes.items():
        rel = stream_reliability(process.filter, streams, truth, num_bins=12)
        used = rel.count > 0
        share = (rel.count[used] / rel.count.sum()).numpy()
        colour = figures.color(name)
        ax.plot(
            rel.confidence[used].numpy(),
            rel.accuracy[used].numpy(),
            "-",
            color=colour,
            lw=1.2,
            label=f"{labels.get(name, name)} (ECE {rel.ece:.3f})",
        )
        ax.scatter(
            rel.confidence[used].numpy(), rel.accuracy[used].numpy(), s=20 + 400 * share, color=colour, alpha=0.7
        )
    ax.axvline(threshold, color="0.3", lw=0.8, ls=":", label=f"threshold {threshold:g}")
    ax.set_xlim(low, 1.0)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("top posterior probability (binned)", fontsize=figures.LABEL_SIZE)
    ax.set_ylabel("share of prefixes whose top class is right", fontsize=figures.LABEL_SIZE)
    ax.set_title("Reliability of each process's filter on the held-out bank", fontsize=figures.TITLE_SIZE)
    ax.tick_params(labelsize=figures.TICK_SIZE)
    ax.legend(fontsize=figures.TICK_SIZE, loc="upper left")
    fig.tight_layout()
    return fig


def report_lines(results: dict[str, dict], labels: dict[str, str], classes: list[str]) -> list[str]:
    """Markdown: each planned policy's distribution check per class, and its value test."""
    lines = [
        "## Honesty of the planning models",
        "",
        "Per class, what the policy's table predicts (accuracy, mean frames) against what its process does "
        "on the held-out bank (95 % Wilson and bootstrap intervals), with parametric-bootstrap p-values of "
        '"one law behind both" (Bonferroni over classes and statistics).',
        "",
    ]
    for name, r in results.items():
        check = r.get("executed", {}).get("distribution_check")
        if check is None:
            continue
        verdict = "passes" if check["passed"] else "fails"
        lines += [
            f"**{labels.get(name, name)}** ({name}) {verdict} in every class."
            if check["passed"]
            else f"**{labels.get(name, name)}** ({name}) {verdict} in "
            f"{', '.join(classes[c] for c, e in enumerate(check['classes']) if not e['passed'])}"
            f" (per-test level {check['alpha_per_test']:.4f}).",
            "",
            "| class | table accuracy | held-out accuracy [95 %] | p | table frames | held-out frames [95 %] | p | |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for c, e in enumerate(check["classes"]):
            lo, hi = e["accuracy_interval"]
            flo, fhi = e["frames_interval"]
            lines.append(
                f"| {classes[c]} | {e['predicted_accuracy']:.3f} | {e['bank_accuracy']:.3f} [{lo:.3f}, {hi:.3f}]"
                f" | {e['accuracy_p']:.3f} | {e['predicted_frames']:.2f} | {e['bank_frames']:.2f} "
                f"[{flo:.2f}, {fhi:.2f}] | {e['frames_p']:.3f} | {'ok' if e['passed'] else 'FAIL'} |"
            )
        test = r["executed"].get("value_test")
        if test:
            need = test["sequences_for_target"]
            lines += [
                "",
                f"Value test (one-sided, level {test['alpha']:g}: does the executed value fall short of the planned "
                f"one?): p = {test['p_value']:.3f}, {'passes' if test['passed'] else 'FAILS'}; power "
                f"{test['power']:.2f} against a {100 * test['shortfall']:.0f} % shortfall (full s.e. "
                f"{test['total_stderr']:.3f}); {100 * test['target_power']:.0f} % power needs "
                + (
                    "more than any bank: the planned and executed values' rollout errors and the table's "
                    "sequences alone are too large"
                    if math.isinf(need)
                    else f"{need:.0f} held-out sequences per class"
                )
                + ".",
            ]
        lines.append("")
    return lines
