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

from hbni_pyro.density import concentrations
from hbni_pyro.fit import fit_many
from hbni_pyro.generative import (
    gamma_variates,
    sample_dirichlet,
    sample_outputs,
    sample_sequences,
)
from hbni_pyro.model import HyperPrior
from hbni_pyro.sequence_model import hyper_scales, look_prior_mean
from hbni_pyro.validation import DTYPE
from hbni_pyro.variants import check_model
from hbni_pyro.wishart import sample_wishart
from infra.streams import stream_seed


def draw_prior(model: str, hyperprior: HyperPrior, num_classes: int, num_draws: int, generator: torch.Generator) -> dict[str, Tensor]:
    """``num_draws`` joint draws of ``model``'s parameters from its prior: site -> ``(num_draws, ...)``."""
    h, n, M, g = hyperprior, num_draws, num_classes, generator
    if check_model(model) in ("paper", "confusion"):
        kappa = gamma_variates(torch.full((n,), h.beta), h.eta, g)
        gamma = gamma_variates(torch.full((n,), h.nu), h.omega, g)
        out = {"theta": gamma_variates(kappa.unsqueeze(-1).expand(n, M), gamma.unsqueeze(-1), g), "kappa": kappa, "gamma": gamma}
        if model == "confusion":
            loc = h.offdiag_loc_sd * torch.randn(n, generator=g, dtype=DTYPE)
            scale = h.offdiag_scale_sd * torch.randn(n, generator=g, dtype=DTYPE).abs()
            log_beta = loc[:, None, None] + scale[:, None, None] * torch.randn(n, M, M, generator=g, dtype=DTYPE)
            out.update(beta=log_beta.exp().masked_fill(torch.eye(M, dtype=torch.bool), 1.0), beta_loc=loc, beta_scale=scale)
        return out
    d = M - 1
    sc = hyper_scales(h, d)
    pool = (math.log(h.between_pooling_median) + h.between_pooling_sd * torch.randn(n, generator=g, dtype=DTYPE)).exp()
    mean = sample_wishart(torch.full((n,), sc["between_df"], dtype=DTYPE), torch.linalg.cholesky(sc["between_scale"]).expand(n, d, d), g)
    psi_inv = torch.linalg.inv(pool[:, None, None, None] * mean.unsqueeze(1)).expand(n, M, d, d)
    between = torch.linalg.inv(sample_wishart((pool + d + 1)[:, None].expand(n, M), torch.linalg.cholesky(psi_inv), g))
    within_prec = sample_wishart(torch.full((n,), sc["within_df"], dtype=DTYPE),
                                 torch.linalg.cholesky(torch.linalg.inv(sc["within_psi"])).expand(n, d, d), g)
    loc = look_prior_mean(M, h.look_vertex) + h.look_sd * torch.randn(n, M, d, generator=g, dtype=DTYPE)
    return {"loc": loc, "between": between, "between_mean": mean, "between_pooling": pool, "within": torch.linalg.inv(within_prec)}


def simulate(model: str, params: dict[str, Tensor], classes: Tensor, num_frames: int, generator: torch.Generator) -> Tensor:
    """Outputs of one dataset from one parameter draw (site -> unbatched tensor).

    Frame-level models: ``classes (N,)`` -> ``(N, M)`` (``num_frames`` ignored). Sequence model:
    ``classes (K,)`` of the sequences -> ``(K * num_frames, M)``, sequence by sequence.
    """
    if model == "paper":
        return sample_outputs(params["theta"], classes, generator)
    if model == "confusion":
        return sample_dirichlet(concentrations(params["theta"], params["beta"])[classes], generator)
    seqs = sample_sequences(params["loc"], params["between"], params["within"], classes, num_frames, generator)
    return seqs.reshape(-1, seqs.shape[-1])


def rank_statistics(model: str, params: dict[str, Tensor]) -> dict[str, Tensor]:
    """The scalar functionals whose ranks SBC checks, site draws ``(n, ...)`` -> name -> ``(n,)``."""
    if model in ("paper", "confusion"):
        stats = {f"log theta[{m}]": params["theta"][:, m].log() for m in range(params["theta"].shape[1])}
        stats.update({"log kappa": params["kappa"].log(), "log gamma": params["gamma"].log()})
        if model == "confusion":
            off = ~torch.eye(params["beta"].shape[-1], dtype=torch.bool)
            stats.update({"log beta[0, 1]": params["beta"][:, 0, 1].log(), "log beta[2, 0]": params["beta"][:, 2, 0].log(),
                          "mean log beta": params["beta"][:, off].log().mean(-1), "beta_loc": params["beta_loc"],
                          "beta_scale": params["beta_scale"]})
        return stats
    stats = {f"loc[{c}, 0]": params["loc"][:, c, 0] for c in range(params["loc"].shape[1])}
    stats.update({f"log|between[{c}]|": torch.logdet(params["between"][:, c]) for c in range(params["between"].shape[1])})
    stats.update({"log between_pooling": params["between_pooling"].log(), "log|within|": torch.logdet(params["within"]),
                  "within[0, 1]": params["within"][:, 0, 1], "log|between_mean|": torch.logdet(params["between_mean"])})
    return stats


class SBCResult(NamedTuple):
    """Ranks ``name -> (D,)`` in ``0..num_draws``, the number of thinned draws, and per statistic the
    chi-square statistic of the ranks' histogram over ``num_bins`` equal bins and its p-value."""

    ranks: dict[str, Tensor]
    num_draws: int
    chi2: dict[str, float]
    p_value: dict[str, float]


def run_sbc(
    model: str, num_datasets: int, num_classes: int = 3, size: int = 30, num_frames: int = 5, *, labelled: bool = True,
    num_chains: int = 4, num_samples: int = 400, warmup_steps: int = 300, thin: int = 16, num_bins: int = 10,
    hyperprior: HyperPrior | None = None, fit_hyperprior: HyperPrior | None = None, seed: int = 0,
) -> SBCResult:
    """SBC of ``model``'s MH kernel on ``num_datasets`` datasets drawn from its own prior.

    Each dataset has ``size`` outputs (frame-level models) or ``size`` sequences of ``num_frames``
    frames (sequence model), balanced over the classes, labelled or not. Ranks use every
    ``thin``-th post-warm-up draw of every chain (thinning makes the draws near-independent).
    ``fit_hyperprior`` (default: ``hyperprior``) fits with another prior than the data's, to show
    that the check has power.
    """
    hp = hyperprior or HyperPrior()
    g = torch.Generator().manual_seed(seed)
    truth = draw_prior(model, hp, num_classes, num_datasets, g)
    classes = torch.arange(num_classes).repeat_interleave(math.ceil(size / num_classes))[:size]
    data = torch.stack([simulate(model, {k: v[i] for k, v in truth.items()}, classes, num_frames, g) for i in range(num_datasets)])
    sequence = model == "sequence"
    labels = classes.repeat_interleave(num_frames) if sequence else classes
    ids = torch.arange(size).repeat_interleave(num_frames) if sequence else None
    posts = fit_many(
        data, labels.expand(num_datasets, -1) if labelled else None, model=model, sequence_ids=ids, num_chains=num_chains,
        num_samples=num_samples, warmup_steps=warmup_steps, seed=stream_seed(seed, "fit"), progress=False, hyperprior=fit_hyperprior or hp,
    )
    true_stats = rank_statistics(model, truth)
    ranks: dict[str, list[int]] = {k: [] for k in true_stats}
    num_draws = (num_chains * (num_samples // thin) + 1) // num_bins * num_bins - 1  # ranks 0..L fill the bins evenly
    for i, post in enumerate(posts):
        draws = {k: v[:, thin - 1 :: thin].reshape((-1,) + v.shape[2:])[:num_draws] for k, v in post.samples.items()}
        for k, v in rank_statistics(model, draws).items():
            ranks[k].append(int((v < true_stats[k][i]).sum()))
    out = {k: torch.tensor(v) for k, v in ranks.items()}
    chi2, p = {}, {}
    for k, r in out.items():
        counts = torch.bincount((r * num_bins) // (num_draws + 1), minlength=num_bins).to(DTYPE)
        expected = num_datasets / num_bins
        chi2[k] = float(((counts - expected) ** 2 / expected).sum())
        p[k] = float(torch.special.gammaincc(torch.tensor((num_bins - 1) / 2, dtype=DTYPE), torch.tensor(chi2[k] / 2, dtype=DTYPE)))
    return SBCResult(out, num_draws, chi2, p)
