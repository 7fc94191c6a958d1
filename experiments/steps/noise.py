"""Noise-fitting step: HBNI on classifier outputs whose true classes are known."""

from __future__ import annotations

import torch
from hydra.utils import instantiate

import hbni_pyro
from experiments.schemas.blocks import HBNIBlock
from hbni_infra.streams import stream_seed


def fit_labelled(
    outputs: torch.Tensor,
    hbni: HBNIBlock,
    seed: int,
    progress: bool,
    model: str | None = None,
    *,
    class_names: list[str] | None = None,
) -> hbni_pyro.HBNIPosterior:
    """Fit HBNI on ``outputs (C, S, F, M)``: ``S`` sequences of ``F`` frames of each true class ``c``.

    Uses the noise model ``model`` (default ``hbni.model``), the ``hbni.fit`` sampler settings and
    the ``hbni.hyperprior``; every output's class is known, and so is its sequence. ``class_names`` name the
    ``C`` classes (the outputs' column order), and travel with the posterior (``None``: unnamed).
    """
    num_classes, num_seq, frames = outputs.shape[:3]
    labels = torch.arange(num_classes).view(-1, 1, 1).expand(outputs.shape[:3]).reshape(-1)
    sequence_ids = torch.arange(num_classes * num_seq).repeat_interleave(frames)
    return hbni_pyro.fit(
        outputs.reshape(-1, outputs.shape[-1]).double(),
        labels,
        model=model or hbni.model,
        sequence_ids=sequence_ids,
        **hbni.fit.kwargs(),
        hyperprior=instantiate(hbni.hyperprior),
        seed=seed,
        progress=progress,
        class_names=class_names,
    )


def stop_folds(
    outputs: torch.Tensor,
    hbni: HBNIBlock,
    seed: int,
    *stream: str,
    folds: int = 2,
    model: str | None = None,
    temper: float = 1.0,
    progress: bool = False,
) -> list[hbni_pyro.Fold]:
    """:func:`hbni_pyro.cross_fit` of HBNI on labelled ``outputs (C, S, F, M)``: fold ``k``'s filter (mode
    ``hbni.filter.mode``, ``temper``) comes from :func:`fit_labelled` on the other folds, seeded by the stream
    ``(*stream, "stop fold", k)`` under ``seed``, for choosing a stop on sequences it was not fitted on."""

    def fit_fold(train: torch.Tensor, k: int) -> hbni_pyro.HBNIFilter:
        posterior = fit_labelled(train, hbni, stream_seed(seed, *stream, "stop fold", k), progress, model)
        return hbni_pyro.make_filter("hbni", posterior, mode=hbni.filter.mode, temper=temper)

    return hbni_pyro.cross_fit(fit_fold, outputs, folds)
