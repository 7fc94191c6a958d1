"""The paper's hardware perception study, replayed on rendered frames.

1. Train the frame classifier's SVM head on ``train_per_class`` training-condition snapshots
   per vehicle class (bright light, plain background), with random crops and mirrors.
2. Render labelled mission-condition sequences (dim, drifting light, motion blur, sensor
   noise, textured background, moving camera), classify every frame, and fit HBNI on those
   outputs with the labels known.
3. On ``test_sequences`` held-out mission sequences per class, run SSBF and the HBNI filter
   and record, per class and method, the end accuracy (argmax of the posterior after the last
   frame is the true class) and the frames needed to put ``threshold`` on the true class.

Backbone features are computed once per frame and reused by everything downstream. The three
image sets use different seeds, so test sequences never overlap training or calibration.
The hardest class is the one with the lowest per-frame classifier accuracy on the test frames.
Writes ``classifier.safetensors``, ``hbni_posterior.safetensors``, ``replay_sequence.png``
(raw outputs, SSBF and HBNI posteriors over one test sequence of the hardest class: the first
one HBNI ends right on and SSBF wrong, else sequence 0; its index is in the metrics) and
``accuracy_vs_frames.png`` (per class, the share of sequences whose argmax is right after n frames).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import torch

import hbni_pyro
from classifiers.data import get_conditions
from experiments.runs.artifacts import save_artifact
from experiments.runs.outputs import save_figure
from experiments.schemas.noise_studies import PerceptionReplay
from experiments.steps.classification import sequence_outputs, train_classifier
from experiments.steps.noise import fit_labelled
from hbni_infra.streams import stream_seed


def _frames_to_reach(post: torch.Tensor, true: int, threshold: float) -> torch.Tensor:
    """First frame (1-based) with ``post[..., true] >= threshold`` per sequence; NaN if never."""
    hit = post[..., true] >= threshold  # (S, N)
    first = hit.float().argmax(-1) + 1
    return torch.where(hit.any(-1), first.float(), torch.tensor(float("nan")))


def run(settings: PerceptionReplay, run_dir: Path) -> dict:
    st = settings.study
    classes = list(st.classes)
    seed, progress = settings.seed, settings.progress
    mission = get_conditions("mission", **st.mission)

    # 1. Train the head on training-condition snapshots (+ crops and mirrors).
    clf = train_classifier(settings.classifier, classes, st.train_per_class, st.augment, seed, progress)
    save_artifact(run_dir, "classifier", clf)

    # 2. Fit HBNI on labelled mission-condition outputs.
    frames = st.frames
    calib, _ = sequence_outputs(
        clf,
        classes,
        st.calib_sequences,
        frames,
        mission,
        stream_seed(seed, "calibration"),
        progress,
        "calibration",
    )
    posterior = fit_labelled(calib, settings.hbni, seed, progress, class_names=list(classes))
    save_artifact(run_dir, "hbni_posterior", posterior)

    # 3. SSBF vs HBNI on held-out sequences.
    test, thumbs = sequence_outputs(
        clf, classes, st.test_sequences, frames, mission, stream_seed(seed, "test"), progress, "test"
    )
    test = test.double()
    filters = {
        name: hbni_pyro.make_filter(name, posterior, **({"mode": settings.hbni.filter.mode} if name == "hbni" else {}))
        for name in ("ssbf", "hbni")
    }
    posts = {k: f.run(test.reshape(-1, frames, len(classes))).view(test.shape) for k, f in filters.items()}
    per_class = _per_class(test, posts, classes, st.threshold)
    hardest = min(classes, key=lambda n: per_class[n]["frame_accuracy"])
    overall = {k: float(np.mean([per_class[n][k]["end_accuracy"] for n in classes])) for k in posts}
    gap = per_class[hardest]["hbni"]["end_accuracy"] - per_class[hardest]["ssbf"]["end_accuracy"]

    h = classes.index(hardest)
    disagree = ((posts["hbni"][h, :, -1].argmax(-1) == h) & (posts["ssbf"][h, :, -1].argmax(-1) != h)).nonzero()
    shown = int(disagree[0]) if len(disagree) else 0
    save_figure(
        _sequence_figure(test[h, shown], posts, h, shown, classes, thumbs[h, shown], st.threshold),
        run_dir / "replay_sequence.png",
    )
    save_figure(_accuracy_figure(per_class, classes), run_dir / "accuracy_vs_frames.png")
    return {
        "classes": classes,
        "per_class": per_class,
        "overall_end_accuracy": overall,
        "hardest_class": hardest,
        "hardest_hbni_minus_ssbf": gap,
        "acceptance": {"hardest_gap_ge_0.15": gap >= 0.15, "overall_hbni_ge_ssbf": overall["hbni"] >= overall["ssbf"]},
        "theta_summary": {k: v for k, v in posterior.summary().items() if k.startswith("theta")},
        "figure_sequence": {"class": hardest, "index": shown},
        "sizes": {
            "train_images": len(classes) * st.train_per_class * (1 + st.augment),
            "calibration_frames": int(calib[..., 0].numel()),
            "test_sequences_per_class": st.test_sequences,
            "frames_per_sequence": frames,
        },
        "mission_conditions": mission.to_dict(),
    }


def _per_class(
    test: torch.Tensor, posts: dict[str, torch.Tensor], classes: list[str], threshold: float
) -> dict[str, Any]:
    """Per class: frame accuracy, mean output, and each filter's end accuracy, accuracy by frame and
    frames to put ``threshold`` on the true class (``test`` and each posterior ``(C, S, N, M)``)."""
    per_class: dict[str, Any] = {}
    for c, name in enumerate(classes):
        entry = {
            "frame_accuracy": float((test[c].argmax(-1) == c).double().mean()),
            "mean_output": test[c].mean((0, 1)),
        }
        for k, post in posts.items():
            reach = _frames_to_reach(post[c], c, threshold)
            entry[k] = {
                "end_accuracy": float((post[c, :, -1].argmax(-1) == c).double().mean()),
                "accuracy_by_frame": (post[c].argmax(-1) == c).double().mean(0),
                "frames_to_threshold_mean": float(reach.nanmean()) if reach.isfinite().any() else None,
                "frames_to_threshold_median": float(reach.nanmedian()) if reach.isfinite().any() else None,
                "reached_fraction": float(reach.isfinite().double().mean()),
            }
        per_class[name] = entry
    return per_class


def _sequence_figure(obs, posts, h, s, classes, frames_img, threshold) -> plt.Figure:
    n = obs.shape[0]
    x = np.arange(1, n + 1)
    fig = plt.figure(figsize=(11, 8.5))
    grid = fig.add_gridspec(4, 1, height_ratios=[0.9, 1, 1, 1], hspace=0.45)
    ax0 = fig.add_subplot(grid[0])
    picks = np.linspace(0, n - 1, min(n, 6)).round().astype(int)
    ax0.imshow(np.hstack([frames_img[i][..., ::-1] for i in picks]))
    ax0.set_axis_off()
    ax0.set_title(f"true class: {classes[h]} (held-out sequence {s}); frames {', '.join(str(i + 1) for i in picks)}")
    panels = [
        ("raw classifier output", obs),
        ("SSBF posterior", posts["ssbf"][h, s]),
        ("HBNI posterior", posts["hbni"][h, s]),
    ]
    for k, (title, y) in enumerate(panels):
        ax = fig.add_subplot(grid[k + 1])
        for m, name in enumerate(classes):
            ax.plot(x, y[:, m].numpy(), marker="o", ms=3, lw=2.2 if m == h else 1.2, label=name)
        ax.axhline(threshold, color="grey", ls=":", lw=1)
        ax.set_ylim(-0.03, 1.03)
        ax.set_ylabel("probability")
        ax.set_title(title)
        if k == 0:
            ax.legend(loc="upper right", ncol=len(classes), fontsize=8)
    ax.set_xlabel("frame")
    return fig


def _accuracy_figure(per_class, classes) -> plt.Figure:
    fig, axes = plt.subplots(1, len(classes), figsize=(4 * len(classes), 3.2), sharey=True)
    for ax, name in zip(np.atleast_1d(axes), classes):
        for k, style in (("ssbf", "--"), ("hbni", "-")):
            acc = per_class[name][k]["accuracy_by_frame"].numpy()
            ax.plot(np.arange(1, len(acc) + 1), acc, style, lw=2, label=k.upper())
        ax.set_title(f"{name} (frame acc {per_class[name]['frame_accuracy']:.2f})")
        ax.set_xlabel("frames seen")
        ax.set_ylim(0, 1.02)
    np.atleast_1d(axes)[0].set_ylabel("sequence accuracy (argmax)")
    np.atleast_1d(axes)[0].legend()
    return fig
