"""Simulation-based calibration (SBC) of the noise models' samplers.

Draw parameters from a model's own prior, simulate a dataset from them, fit it, and find the
rank of each true parameter among the (thinned) posterior draws. If the sampler targets the
right posterior, every rank is uniform over ``0..L`` (Talts et al., 2018). Many datasets are
fitted at once with :func:`hbni_pyro.fit_many`, so one vectorised MH program does the whole study.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.fit import fit_many
from hbni_pyro.models import NoiseModel, noise_model
from hbni_pyro.validation import DTYPE
from hbni_infra.streams import stream_seed, torch_generator
from hbni_infra.checks import as_int, as_seed


class SBCResult(NamedTuple):
    """Ranks ``name -> (D,)`` in ``0..num_draws``, the number of thinned draws, and per statistic the
    chi-square statistic of the ranks' histogram over ``num_bins`` equal bins and its p-value."""

    ranks: dict[str, Tensor]
    num_draws: int
    chi2: dict[str, float]
    p_value: dict[str, float]


def run_sbc(
    model: str | NoiseModel,
    num_datasets: int,
    num_classes: int = 3,
    size: int = 30,
    num_frames: int = 5,
    *,
    labelled: bool = True,
    num_chains: int = 4,
    num_samples: int = 400,
    warmup_steps: int = 300,
    thin: int = 16,
    num_bins: int = 10,
    hyperprior: HyperPrior | None = None,
    fit_hyperprior: HyperPrior | None = None,
    seed: int = 0,
) -> SBCResult:
    """SBC of ``model``'s MH kernel on ``num_datasets`` datasets drawn from its own prior.

    Each dataset has ``size`` outputs (frame-level models) or ``size`` sequences of ``num_frames``
    frames (sequence model), balanced over the classes, labelled or not. Ranks use every
    ``thin``-th post-warm-up draw of every chain (thinning makes the draws near-independent).
    ``fit_hyperprior`` (default: ``hyperprior``) fits with another prior than the data's, to show
    that the check has power.
    """
    spec = noise_model(model)
    num_datasets, num_classes = as_int("num_datasets", num_datasets, 1), as_int("num_classes", num_classes, 2)
    size, num_frames = as_int("size", size, 1), as_int("num_frames", num_frames, 1)
    thin, num_bins, seed = as_int("thin", thin, 1), as_int("num_bins", num_bins, 2), as_seed("seed", seed)
    if spec.draw_prior is None or spec.simulate is None or spec.rank_statistics is None:
        raise ValueError(
            f"model: the {spec.name!r} noise model has no draw_prior, simulate and rank_statistics for SBC"
        )
    hp = hyperprior or HyperPrior()
    g = torch_generator(seed)
    truth = spec.draw_prior(hp, num_classes, num_datasets, g)
    classes = torch.arange(num_classes).repeat_interleave(math.ceil(size / num_classes))[:size]
    data = torch.stack(
        [spec.simulate({k: v[i] for k, v in truth.items()}, classes, num_frames, g) for i in range(num_datasets)]
    )
    sequence = spec.sequences
    labels = classes.repeat_interleave(num_frames) if sequence else classes
    ids = torch.arange(size).repeat_interleave(num_frames) if sequence else None
    posts = fit_many(
        data,
        labels.expand(num_datasets, -1) if labelled else None,
        model=spec,
        sequence_ids=ids,
        num_chains=num_chains,
        num_samples=num_samples,
        warmup_steps=warmup_steps,
        seed=stream_seed(seed, "fit"),
        progress=False,
        hyperprior=fit_hyperprior or hp,
    )
    true_stats = spec.rank_statistics(truth)
    ranks: dict[str, list[int]] = {k: [] for k in true_stats}
    num_draws = (num_chains * (num_samples // thin) + 1) // num_bins * num_bins - 1  # ranks 0..L fill the bins evenly
    for i, post in enumerate(posts):
        draws = {k: v[:, thin - 1 :: thin].reshape((-1,) + v.shape[2:])[:num_draws] for k, v in post.samples.items()}
        for k, v in spec.rank_statistics(draws).items():
            ranks[k].append(int((v < true_stats[k][i]).sum()))
    out = {k: torch.tensor(v) for k, v in ranks.items()}
    chi2, p = {}, {}
    for k, r in out.items():
        counts = torch.bincount((r * num_bins) // (num_draws + 1), minlength=num_bins).to(DTYPE)
        expected = num_datasets / num_bins
        chi2[k] = float(((counts - expected) ** 2 / expected).sum())
        p[k] = float(
            torch.special.gammaincc(
                torch.tensor((num_bins - 1) / 2, dtype=DTYPE), torch.tensor(chi2[k] / 2, dtype=DTYPE)
            )
        )
    return SBCResult(out, num_draws, chi2, p)
