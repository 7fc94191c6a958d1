"""One figure style: a policy has the same colour in values.png and closed_loop.png, and panels wrap into rows."""

import matplotlib.colors as mcolors
import numpy as np
import torch

import hbni_pyro
from experiments.reports import figures, mission_report
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


def _segments(n):
    from hbni_pyro import Segment

    names = ["ambulance", "police_car", "medical_copter", "news_copter", "food_crate", "medical_crate"]
    segs, beliefs, thumbs, start = [], [], [], 0
    for i in range(n):
        frames, label = 2 + i % 5, i % 6
        segs.append(
            Segment(
                i,
                start,
                start + frames - 1,
                label,
                names[label],
                0.97,
                frames,
                False,
                False,
                torch.zeros(frames, 6),
                [],
            )
        )
        beliefs.append(torch.linspace(0.3, 0.97, frames))
        thumbs.append(np.full((30, 40, 3), 20 * i % 255, dtype=np.uint8))
        start += frames
    return segs, beliefs, thumbs, names


def test_the_stream_strip_says_what_it_shows_and_keeps_colours_apart():
    from experiments.steps.annotate import strip_figure

    segs, beliefs, thumbs, names = _segments(20)
    fig = strip_figure(segs, beliefs, thumbs, names, 0.95, "strip")
    timeline = fig.axes[-1]
    assert "frames shown for 8 of them" in timeline.get_title()  # the subsampling is said, not silent
    assert len(fig.axes) == 9
    line_colours = {mcolors.to_rgb(line.get_color()) for line in timeline.lines if line.get_linestyle() == "-"}
    class_colours = {mcolors.to_rgb(figures.class_color(c)) for c in range(len(names))}
    assert line_colours == {mcolors.to_rgb(figures.CONFIDENCE_COLOR)} and not line_colours & class_colours
    assert len(class_colours) == len(names)
    fig.canvas.draw()
    legend = timeline.get_legend().get_window_extent()
    assert legend.x0 >= timeline.get_window_extent().x1  # beside the axes: it covers no tick or point
    few = strip_figure(*_segments(3), 0.95, "strip")
    assert "frames shown" not in few.axes[-1].get_title() and len(few.axes) == 4
