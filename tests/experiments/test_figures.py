"""One figure style: a policy has the same colour in values.png and closed_loop.png, and panels wrap into rows."""

import matplotlib.colors as mcolors
import torch

import hbni_pyro
from experiments import figures, mission_report
from experiments.steps import closed_loop


def _results():
    names = ("perfect", "hbni", "ssbf", "max_of_mean", "hbni_generative")
    entry = {
        "value": 5.0,
        "stderr": 0.1,
        "greedy": {"value": 4.8},
        "delivered_per_rollout": 7.0,
        "wrong_per_rollout": 0.2,
        "executed": {"value": 4.9, "stderr": 0.1, "gap_in_stderr": -1.0, "gap_in_total_stderr": -0.5},
    }
    return {n: entry for n in names}


def test_a_policy_keeps_its_colour_across_figures():
    results = _results()
    values = mission_report.value_figure(results).axes[0].patches
    loop = closed_loop.figure(results, figures.LABELS).axes[0].patches
    n = len(results)
    for k, name in enumerate(results):
        want = mcolors.to_rgb(figures.color(name))
        assert mcolors.to_rgb(values[k].get_facecolor()) == want
        assert mcolors.to_rgb(loop[k].get_facecolor()) == want and mcolors.to_rgb(loop[n + k].get_facecolor()) == want


def test_panels_wrap_and_the_confusion_figure_has_a_colour_bar():
    joint = torch.full((6, 6, 3), 1 / 18, dtype=torch.float64)
    model = hbni_pyro.MacroObservationModel(joint, torch.zeros(6))
    fig = mission_report.confusion_figure({name: model for name in ("hbni", "ssbf", "max_of_mean", "hbni_generative")})
    width, height = fig.get_size_inches()
    assert width < 16 and height > 6  # two rows of at most three panels, not one wide strip
    assert any(ax.get_label() == "<colorbar>" for ax in fig.axes)
