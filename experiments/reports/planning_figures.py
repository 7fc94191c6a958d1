"""Figures and tables of the planning experiments: values of policies, G-DICE and planner learning curves."""

from __future__ import annotations

import matplotlib.pyplot as plt


def bar_figure(
    entries: dict[str, dict[str, float]], title: str, reference: dict[str, float] | None = None
) -> plt.Figure:
    """Bar chart of value +- stderr per policy (optionally with dashed reference lines)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    names = list(entries)
    colors = ["tab:red", "tab:blue", "tab:orange", "tab:green", "tab:gray", "tab:purple", "tab:brown"]
    ax.bar(
        names,
        [entries[n]["value"] for n in names],
        yerr=[entries[n]["stderr"] for n in names],
        capsize=4,
        color=[colors[i % len(colors)] for i in range(len(names))],
    )
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
    """A cross-entropy run's best sample so far, the iteration's best elite score and its samples' mean score
    against iteration."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    its = [i + 1 for i, phase in enumerate(history["phase"]) if phase == 0]
    for key, label, alpha in (
        ("best_sampled", "best sampled so far", 1.0),
        ("challenger_value", "iteration best", 0.7),
        ("mean", "iteration mean", 0.7),
    ):
        ax.plot(its, [history[key][i - 1] for i in its], label=label, alpha=alpha)
    ax.set_xlabel("G-DICE iteration")
    ax.set_ylabel("value (Monte Carlo estimate)")
    ax.set_title(title)
    ax.legend()
    return fig


def planner_figure(history: dict[str, list[float]], title: str) -> plt.Figure:
    """The cold-start planner's incumbent value (its duel mean on fresh rollouts) against rollouts spent."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    points = [(r / 1e6, v, p) for r, v, p in zip(history["rollouts"], history["value"], history["phase"]) if v == v]
    if points:
        x, v, phase = zip(*points)
        ax.step(x, v, where="post", color="k", lw=1, label="incumbent")
        for which, label, color in (
            (0, "after a cross-entropy phase", "tab:orange"),
            (1, "after a local-search step", "tab:blue"),
        ):
            sel = [(a, b) for a, b, p in points if p == which]
            if sel:
                ax.plot(*zip(*sel), ".", color=color, label=label)
    ax.set_xlabel("rollouts spent (millions)")
    ax.set_ylabel("value on fresh rollouts")
    ax.set_title(title)
    ax.legend(fontsize=8)
    return fig


def comparison_table(entries: dict[str, dict[str, float]]) -> list[str]:
    """Markdown rows: each policy's re-evaluated value +- s.e., and its search cost where it has one."""
    rows = ["| policy | value ± s.e. | search rollouts | search CPU s |", "|---|---|---|---|"]
    for name, e in entries.items():
        rollouts = f"{e['rollouts']:,}" if "rollouts" in e else "–"
        cpu = f"{e['cpu_seconds']:.0f}" if "cpu_seconds" in e else "–"
        rows.append(f"| {name} | {e['value']:.3f} ± {e['stderr']:.3f} | {rollouts} | {cpu} |")
    return rows
