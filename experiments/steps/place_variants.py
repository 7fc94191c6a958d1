"""The new-place study's filters, each fitted on exactly what it may use (:mod:`experiments.studies.new_place`).

- ``hbni_old``: HBNI fitted on the old place's labels, stopping where its labels kept the promise on held-out folds
  there (what the mission does, carried to the new place);
- ``calibrated_K<k>``: the calibrated peer (per-frame calibration + SSBF with its evidence weight) on the ``k``
  labelled new-place sequences per class, or on the old place's labelled frames when ``k = 0``;
- ``hbni_K<k>``: HBNI adapted from the old posterior on the ``k`` labelled and ``U`` unlabelled new-place sequences
  (:func:`hbni_pyro.adapt`), stopping at the confidence that keeps the promise on those streams, the unlabelled ones
  scored by its own posterior given each whole stream (:func:`hbni_pyro.fit_stop_unlabelled`).

The rendered mission and the photographs (:mod:`experiments.steps.place_photos`) both fit them here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import torch
from hydra.utils import instantiate
from tqdm.auto import tqdm

import hbni_pyro
from experiments.runs.artifacts import save_artifact
from experiments.schemas.new_place_study import NewPlace
from experiments.steps.noise import fit_labelled, stop_folds
from hbni_infra.streams import stream_seed

STOPS = tuple(round(0.5 + 0.01 * i, 2) for i in range(50)) + (0.995, 0.999)
"""Candidate stops of the adapted models' label-free stop: every hundredth, for a stop as low as the promise allows."""


class PlaceData(NamedTuple):
    """Classifier outputs (float64, columns in class order): the old place's labelled sequences ``(C, S, F, C)``,
    the new place's labelled pool ``(C, K max, F, C)``, its unlabelled streams ``(U, F, C)`` and their classes
    ``(U,)`` (known only to the report)."""

    old: torch.Tensor
    labelled: torch.Tensor
    unlabelled: torch.Tensor
    unlabelled_truth: torch.Tensor

    @classmethod
    def of(cls, tensors: dict[str, torch.Tensor]) -> PlaceData:
        """From cached tensors by field name, outputs as float64."""
        return cls(*(tensors[k] if k == "unlabelled_truth" else tensors[k].double() for k in cls._fields))


class Variant(NamedTuple):
    """A filter fitted on what it may use: its process, the posterior its table is simulated from, its family
    (``hbni_old``, ``calibrated``, ``hbni``), the labelled sequences per class ``K`` it used and how it stops."""

    process: hbni_pyro.MacroObservationProcess
    model: hbni_pyro.HBNIPosterior
    family: str
    K: int
    stop: dict[str, Any]


def say(settings: NewPlace, message: str) -> None:
    """A progress line of the study (with ``progress``)."""
    if settings.progress:
        tqdm.write(f"[new_place] {message}")


def fit_variants(
    data: PlaceData, settings: NewPlace, seed: int, run_dir: Path, classes: list[str]
) -> dict[str, Variant]:
    """Every filter of the study (the module docstring's list), its models drawn from streams under ``seed`` and
    saved in ``run_dir``; ``classes`` name the outputs' columns."""
    st, M = settings.new_place, len(classes)
    F = data.old.shape[2]
    say(settings, "fitting HBNI on the old place's labels and choosing its stop on held-out folds there")
    old = fit_labelled(data.old, settings.hbni, stream_seed(seed, "fit"), settings.progress, class_names=classes)
    save_artifact(run_dir, "posterior_old", old)
    folds = stop_folds(data.old, settings.hbni, seed, "fit", folds=st.old.stop_folds, progress=settings.progress)
    old_stop = hbni_pyro.fit_stop_threshold(folds, None, None, st.threshold, F)
    mode = settings.hbni.filter.mode
    variants = {
        "hbni_old": Variant(
            process(hbni_pyro.make_filter("hbni", old, mode=mode), old_stop.stop, F),
            old,
            "hbni_old",
            0,
            {"fitted_on": "old place, held-out folds", **old_stop._asdict()},
        )
    }
    for K in st.labelled:
        say(settings, f"K = {K}: the calibrated peer, and HBNI adapted on {K} labelled + the unlabelled streams")
        labelled = data.labelled[:, :K]
        peer = fit_peer(data.old if K == 0 else labelled, st.calibration, run_dir, f"calibration_K{K}", classes)
        known = torch.arange(M).repeat_interleave(K)
        peer_model = old if K == 0 else adapt_to(old, labelled.reshape(-1, F, M), known, settings, seed, "peer", K)
        variants[f"calibrated_K{K}"] = Variant(
            process(peer, st.threshold, F), peer_model, "calibrated", K, {"value": st.threshold}
        )
        streams = torch.cat([labelled.reshape(-1, F, M), data.unlabelled])
        labels = torch.cat([known, torch.full((len(data.unlabelled),), -1)])
        adapted = adapt_to(old, streams, labels, settings, seed, "adapt", K)
        save_artifact(run_dir, f"posterior_K{K}", adapted)
        hbni = hbni_pyro.make_filter("hbni", adapted, mode=mode)
        stop = hbni_pyro.fit_stop_unlabelled(hbni, streams, st.threshold, F, grid=STOPS, labels=labels)
        variants[f"hbni_K{K}"] = Variant(
            process(hbni, stop.stop, F),
            adapted,
            "hbni",
            K,
            {"fitted_on": f"{K} labelled + {len(data.unlabelled)} unlabelled new-place streams", **stop._asdict()},
        )
    return variants


def process(filter: hbni_pyro.StreamingFilter, stop: float, frames: int) -> hbni_pyro.MacroObservationProcess:
    """The macro-observation process of ``filter``, stopping at ``stop`` or after ``frames`` frames."""
    return hbni_pyro.MacroObservationProcess(filter, threshold=stop, max_frames=frames)


def adapt_to(
    old: hbni_pyro.HBNIPosterior,
    streams: torch.Tensor,
    labels: torch.Tensor,
    settings: NewPlace,
    seed: int,
    *stream: Any,
) -> hbni_pyro.HBNIPosterior:
    """``old`` adapted to the new place on ``streams (B, F, M)`` with ``labels (B,)`` (-1 unknown), seeded by the
    stream ``stream`` under ``seed``, with ``new_place``'s prior and ``hbni``'s sampler settings."""
    B, F, M = streams.shape
    st = settings.new_place
    return hbni_pyro.adapt(
        old,
        streams.reshape(-1, M),
        labels.repeat_interleave(F),
        sequence_ids=torch.arange(B).repeat_interleave(F),
        shift_sd=st.shift_sd,
        prevalence=st.prevalence,
        seed=stream_seed(seed, *stream),
        progress=settings.progress,
        hyperprior=instantiate(settings.hbni.hyperprior),
        **settings.hbni.fit.sizes(),
    )


def fit_peer(
    outputs: torch.Tensor, calibration: str, run_dir: Path, name: str, classes: list[str]
) -> hbni_pyro.StreamingFilter:
    """The calibrated peer on labelled sequences ``(C, S, F, C)`` of ``classes``: the per-frame map ``calibration``
    (saved as ``name``), then SSBF's evidence weight fitted on the same sequences (as the mission's)."""
    C, S = outputs.shape[:2]
    labels = torch.arange(C).view(-1, 1, 1).expand(outputs.shape[:3])
    fitted = hbni_pyro.fit_frame_calibration(outputs, labels, calibration, class_names=classes)
    save_artifact(run_dir, name, fitted)
    peer = hbni_pyro.make_filter("calibrated", calibration=fitted)
    truth = torch.arange(C).repeat_interleave(S)
    return peer.tempered(hbni_pyro.fit_temper(peer, outputs.reshape(C * S, *outputs.shape[2:]), truth).temper)


def frame_accuracy(outputs: torch.Tensor) -> float:
    """Share of frames ``(C, S, F, C)`` whose top class is the true one."""
    truth = torch.arange(outputs.shape[0]).view(-1, 1, 1)
    return float((outputs.argmax(-1) == truth).double().mean())
