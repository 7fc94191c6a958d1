"""One style for the experiments' figures: each policy's label and colour, panel grids and annotated heatmaps.

A variant keeps its colour in every figure of a run (``values.png``, ``closed_loop.png``, the learning curves);
two kinds of one quantity (planned and executed) differ by shade, never by hue.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

LABELS = {
    "perfect": "perfect perception",
    "hbni": "HBNI",
    "calibrated": "calibrated + SSBF",
    "ssbf": "SSBF",
    "max_of_mean": "max-of-mean",
    "hbni_generative": "HBNI (generative)",
    "hbni_empirical": "HBNI (empirical)",
}
COLORS = {
    "perfect": "tab:gray",
    "hbni": "tab:blue",
    "calibrated": "tab:red",
    "ssbf": "tab:orange",
    "max_of_mean": "tab:green",
    "hbni_generative": "tab:purple",
    "hbni_empirical": "tab:cyan",
}
CONFIDENCE_COLOR = "black"  # a filter's confidence over frames: no class's colour
THRESHOLD_COLOR = "gray"
TITLE_SIZE, LABEL_SIZE, TICK_SIZE = 11, 10, 9
PANEL_COLUMNS = 3  # panels per row: a figure of many variants wraps instead of growing wide


def label(name: str) -> str:
    """A policy's label in figures and tables."""
    return LABELS.get(name, name)


def color(name: str) -> str:
    """A policy's colour, the same in every figure."""
    return COLORS.get(name, "tab:brown")


def class_color(label: int) -> tuple[float, float, float, float]:
    """Colour of class ``label`` in figures of labels (tab10, then tab20's light shades; never black or gray)."""
    palette = plt.get_cmap("tab10").colors[:7] + plt.get_cmap("tab10").colors[8:]  # tab10 without its gray
    extra = plt.get_cmap("tab20").colors[1::2]
    colours = palette + tuple(c for c in extra if c not in palette)
    return (*colours[label % len(colours)], 1.0)


def panels(count: int, width: float = 4.4, height: float = 3.9, **kwargs) -> tuple[plt.Figure, list[plt.Axes]]:
    """A figure of ``count`` panels, at most :data:`PANEL_COLUMNS` a row; unused cells are hidden."""
    columns = min(count, PANEL_COLUMNS)
    rows = -(-count // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(width * columns, height * rows), squeeze=False, **kwargs)
    flat = list(axes.flat)
    for ax in flat[count:]:
        ax.set_visible(False)
    return fig, flat[:count]


def heatmap(ax: plt.Axes, matrix: np.ndarray, ticks: list[str], title: str):
    """An annotated probability matrix (rows: true class, columns: label) on ``[0, 1]``; returns the image."""
    image = ax.imshow(matrix, vmin=0, vmax=1, cmap="Blues")
    for i in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            ax.text(
                j,
                i,
                f"{matrix[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=TICK_SIZE - 1,
                color="white" if matrix[i, j] > 0.6 else "black",
            )
    ax.set_xticks(range(len(ticks)), ticks, fontsize=TICK_SIZE, rotation=30, ha="right")
    ax.set_yticks(range(len(ticks)), ticks, fontsize=TICK_SIZE)
    ax.set_title(title, fontsize=TITLE_SIZE)
    return image
