"""Figures of the planning experiments: values of policies, G-DICE learning curves."""

from __future__ import annotations

import matplotlib.pyplot as plt


def bar_figure(entries: dict[str, dict[str, float]], title: str, reference: dict[str, float] | None = None) -> plt.Figure:
    """Bar chart of value +- stderr per policy (optionally with dashed reference lines)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    names = list(entries)
    ax.bar(names, [entries[n]["value"] for n in names], yerr=[entries[n]["stderr"] for n in names], capsize=4,
           color=["tab:blue", "tab:orange", "tab:green", "tab:gray", "tab:purple"][: len(names)])
    for label, value in (reference or {}).items():
        ax.axhline(value, ls="--", lw=1, color="k", alpha=0.5)
        ax.text(-0.45, value, label, va="bottom", ha="left", fontsize=8)
    ax.set_ylim(top=1.1 * max([ax.get_ylim()[1], *(reference or {}).values()]))
    ax.set_ylabel("discounted return (mean +- s.e.)")
    ax.set_title(title)
    plt.setp(ax.get_xticklabels(), rotation=20, ha="right")
    fig.tight_layout()
    return fig


def history_figure(history: dict[str, list[float]], title: str) -> plt.Figure:
    """G-DICE's best-so-far, iteration-best and iteration-mean values against iteration."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    its = range(1, len(history["best"]) + 1)
    ax.plot(its, history["best"], label="best sampled so far")
    ax.plot(its, history["iteration_best"], label="iteration best", alpha=0.7)
    ax.plot(its, history["iteration_mean"], label="iteration mean", alpha=0.7)
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("value (Monte Carlo estimate)")
    ax.set_title(title)
    ax.legend()
    return fig
