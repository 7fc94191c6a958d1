"""Characterise HBNI and SSBF macro-observation processes on the paper's toy.

HBNI's noise posterior is fitted on ``3 * training_per_class`` unlabelled outputs. Each
process is characterised twice: on streams from the true theta (what the process really
delivers) and on the HBNI posterior predictive (what a robot that knows only its training
data would tabulate for its planner). Writes ``metrics.json`` (confusion tables, frame-count
distributions, timeout rates), one ``macro_<process>_<source>.safetensors`` per table
(load with ``hbni_pyro.MacroObservationModel.load``) and ``macro_observation.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import torch
from hydra.utils import instantiate

import hbni_pyro
from experiments.runs.outputs import save_figure
from experiments.schemas.noise_studies import MacroObservation, MacroStudy
from hbni_pyro import MacroObservationModel, MacroObservationProcess, characterize, make_filter, sample_outputs
from hbni_pyro.validation import DTYPE
from hbni_infra.streams import stream_seed, torch_stream

COLORS = {"hbni": "tab:blue", "calibrated": "tab:red", "ssbf": "tab:green"}
PEER_CALIBRATION = "temperature"
"""The calibrated peer's per-frame map on the toy: 15 training outputs are too few for the matrix form."""


def run(settings: MacroObservation, run_dir: Path) -> dict:
    s, hbni, progress = settings.study, settings.hbni, settings.progress
    theta = torch.tensor(s.true_theta, dtype=DTYPE)
    M, seed = len(theta), settings.seed
    classes = torch.arange(M).repeat_interleave(s.training_per_class)
    train = sample_outputs(theta, classes, torch_stream(seed, "train"))
    posterior = hbni_pyro.fit(
        train, **hbni.fit.kwargs(), hyperprior=instantiate(hbni.hyperprior), seed=seed, progress=progress
    )
    posterior.save(run_dir / "posterior.safetensors")
    filters = {
        "hbni": make_filter("hbni", posterior, mode=hbni.filter.mode, num_draws=s.filter_draws),
        # the calibrated peer, given the training outputs' labels (HBNI is fitted without them); i.i.d. frames need
        # no evidence weight
        "calibrated": make_filter(
            "calibrated", calibration=hbni_pyro.fit_frame_calibration(train, classes, PEER_CALIBRATION)
        ),
        "ssbf": make_filter("ssbf", num_classes=M),
    }
    sources = {"true_theta": theta, "posterior_predictive": posterior}
    models: dict[str, dict[str, MacroObservationModel]] = {}
    for name, f in filters.items():
        process = MacroObservationProcess(f, threshold=s.threshold, max_frames=s.max_frames)
        models[name] = {}
        for k, (source, generative) in enumerate(sources.items()):
            model = characterize(
                process,
                generative,
                s.num_streams,
                seed=stream_seed(seed, "characterize", k),
                progress=progress,
            )
            model.save(run_dir / f"macro_{name}_{source}.safetensors")
            models[name][source] = model
    save_figure(_figure(models, theta, s), run_dir / "macro_observation.png")
    return {
        "settings": {
            "true_theta": theta,
            "training_outputs": len(classes),
            "threshold": s.threshold,
            "max_frames": s.max_frames,
            "num_streams_per_class": s.num_streams,
            "hbni_filter_mode": hbni.filter.mode,
            "hbni_filter_draws": s.filter_draws,
        },
        "theta_posterior_mean": posterior.theta_draws().mean(0),
        "processes": {name: {src: _describe(m) for src, m in per.items()} for name, per in models.items()},
    }


def _describe(model: MacroObservationModel) -> dict[str, Any]:
    pmf = model.frames_pmf
    cdf = pmf.cumsum(1)
    return {
        "confusion": model.confusion,
        "accuracy": model.accuracy,
        "mean_accuracy": float(model.accuracy.mean()),
        "frames_pmf": pmf,
        "mean_frames": model.mean_frames,
        "median_frames": (cdf >= 0.5).to(torch.int8).argmax(1) + 1,
        "timed_out_rate": model.timed_out,
    }


def _figure(models: dict[str, dict[str, MacroObservationModel]], theta: torch.Tensor, s: MacroStudy) -> plt.Figure:
    M, T = len(theta), s.max_frames
    columns = max(M, len(models) + 1)
    fig, axes = plt.subplots(2, columns, figsize=(4.3 * columns, 7.2))
    frames = np.arange(1, T + 1)
    for c in range(M):
        ax = axes[0, c]
        for name, per in models.items():
            model = per["true_theta"]
            pmf = model.frames_pmf[c].numpy()
            acc = float(model.accuracy[c])
            ax.step(
                frames,
                pmf,
                where="mid",
                color=COLORS[name],
                label=f"{name.upper()}: mean {float(model.mean_frames[c]):.2f} frames, accuracy {acc:.3f}",
            )
        ax.set_xlim(0.5, min(T, 25) + 0.5)
        ax.set_xlabel("frames used")
        ax.set_title(f"true class {c} (θ = {float(theta[c]):g})")
        ax.legend(fontsize=7.5)
    axes[0, 0].set_ylabel("P(frames used | true class)")
    for ax, name in zip(axes[1], models):
        conf = models[name]["true_theta"].confusion.numpy()
        ax.imshow(conf, vmin=0, vmax=1, cmap="Blues")
        for i in range(M):
            for j in range(M):
                ax.text(j, i, f"{conf[i, j]:.3f}", ha="center", va="center", color="w" if conf[i, j] > 0.5 else "k")
        ax.set_xticks(range(M))
        ax.set_yticks(range(M))
        ax.set_xlabel("macro-observation label")
        ax.set_ylabel("true class")
        ax.set_title(f"{name.upper()}: P(label | true class)")
    for ax in axes[0, M:]:
        ax.axis("off")
    for ax in axes[1, len(models) + 1 :]:
        ax.axis("off")
    _mean_frames_bars(axes[1, len(models)], models, M)
    fig.suptitle(
        f"Macro-observations at threshold {s.threshold:g} (true θ = {theta.tolist()}, "
        f"{s.num_streams} streams per class)",
        y=1.0,
    )
    fig.tight_layout()
    return fig


def _mean_frames_bars(ax: plt.Axes, models: dict[str, dict[str, MacroObservationModel]], M: int) -> None:
    width = 0.2
    pairs = [(name, source) for name in models for source in ("true_theta", "posterior_predictive")]
    for k, (name, source) in enumerate(pairs):
        predictive = source == "posterior_predictive"
        ax.bar(
            np.arange(M) + (k - (len(pairs) - 1) / 2) * width,
            models[name][source].mean_frames.numpy(),
            width * 0.9,
            color="none" if predictive else COLORS[name],
            edgecolor=COLORS[name],
            hatch="//" if predictive else None,
            label=f"{name.upper()}, {source.replace('_', ' ')}",
        )
    ax.set_xticks(range(M))
    ax.set_xlabel("true class")
    ax.set_ylabel("mean frames used")
    ax.set_title("mean frames: true θ vs posterior predictive")
    ax.legend(fontsize=7.5)
