"""The sequence-aware model: a latent look per sequence, so a sequence's frames are exchangeable rather than
independent, as one :class:`NoiseModel`; its fits take sequence ids.

Its room holds the Pyro program (:mod:`.program`) with its Wishart priors (:mod:`.wishart`) and look terms
(:mod:`.looks`), the output sampler (:mod:`.sampler`) with the AR(1) correlation of a camera's frames
(:mod:`.correlation`), the MH kernel (:mod:`.kernel`, its steps in :mod:`.steps`, compiled in :mod:`.steps_numba`)
and the filter's evidence (:mod:`.evidence`, compiled in :mod:`.evidence_numba`). Adapted to a new place, the class
means' prior is the old place's looks moved together (:mod:`.shift_prior`), with its kernel moves in
:mod:`.shift_steps`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.models.sequence.correlation import estimate_frame_correlation
from hbni_pyro.models.sequence.evidence import SequenceEvidence
from hbni_pyro.models.sequence.kernel import SequenceMetropolis
from hbni_pyro.models.sequence.sampler import sample_sequences
from hbni_pyro.models.sequence.shift_prior import ShiftPrior
from hbni_pyro.models.sequence.program import (
    SequenceStats,
    hyper_scales,
    look_prior_mean,
    sequence_log_joint,
    sequence_model,
    sequence_prior_log_prob,
    sequence_stats,
    sequence_unit_log_lik,
)
from hbni_pyro.models.sequence.wishart import sample_wishart
from hbni_pyro.models.spec import Draws, NoiseModel
from hbni_pyro.validation import DTYPE

COVARIANCES = ("between", "between_mean", "within")


def site_shapes(num_classes: int) -> dict[str, tuple[int, ...]]:
    M, d = num_classes, num_classes - 1
    return {"loc": (M, d), "between": (M, d, d), "between_mean": (d, d), "between_pooling": (), "within": (d, d)}


def nuts_sites(raw: Draws) -> Draws:
    outer = {k[: -len("_tril")]: v @ v.transpose(-1, -2) for k, v in raw.items() if k.endswith("_tril")}
    return {"loc": raw["loc"], **outer, **{k: v for k, v in raw.items() if k.endswith("_pooling")}}


def sample_streams(
    draws: Draws, true_class: int, num_frames: int, generator: torch.Generator, correlation: float = 0.0
) -> Tensor:
    n = draws["loc"].shape[0]
    return sample_sequences(
        draws["loc"][:, true_class],
        draws["between"][:, true_class],
        draws["within"].unsqueeze(1),
        torch.arange(n, device=draws["loc"].device),
        num_frames,
        generator,
        correlation,
    )


def draw_prior(hyperprior: HyperPrior, num_classes: int, num_draws: int, generator: torch.Generator) -> Draws:
    h, n, M, g = hyperprior, num_draws, num_classes, generator
    d = M - 1
    sc = hyper_scales(h, d)
    pool = (math.log(h.between_pooling_median) + h.between_pooling_sd * torch.randn(n, generator=g, dtype=DTYPE)).exp()
    mean = sample_wishart(
        torch.full((n,), sc["between_df"], dtype=DTYPE), torch.linalg.cholesky(sc["between_scale"]).expand(n, d, d), g
    )
    psi_inv = torch.linalg.inv(pool[:, None, None, None] * mean.unsqueeze(1)).expand(n, M, d, d)
    between = torch.linalg.inv(sample_wishart((pool + d + 1)[:, None].expand(n, M), torch.linalg.cholesky(psi_inv), g))
    within_prec = sample_wishart(
        torch.full((n,), sc["within_df"], dtype=DTYPE),
        torch.linalg.cholesky(torch.linalg.inv(sc["within_psi"])).expand(n, d, d),
        g,
    )
    loc = look_prior_mean(M, h.look_vertex) + h.look_sd * torch.randn(n, M, d, generator=g, dtype=DTYPE)
    return {
        "loc": loc,
        "between": between,
        "between_mean": mean,
        "between_pooling": pool,
        "within": torch.linalg.inv(within_prec),
    }


def simulate(params: Draws, classes: Tensor, num_frames: int, generator: torch.Generator) -> Tensor:
    seqs = sample_sequences(params["loc"], params["between"], params["within"], classes, num_frames, generator)
    return seqs.reshape(-1, seqs.shape[-1])


def rank_statistics(params: Draws) -> dict[str, Tensor]:
    stats = {f"loc[{c}, 0]": params["loc"][:, c, 0] for c in range(params["loc"].shape[1])}
    stats.update(
        {f"log|between[{c}]|": torch.logdet(params["between"][:, c]) for c in range(params["between"].shape[1])}
    )
    stats.update(
        {
            "log between_pooling": params["between_pooling"].log(),
            "log|within|": torch.logdet(params["within"]),
            "within[0, 1]": params["within"][:, 0, 1],
            "log|between_mean|": torch.logdet(params["between_mean"]),
        }
    )
    return stats


NOISE_MODEL = NoiseModel(
    name="sequence",
    summary="a latent look per sequence; frames exchangeable within it",
    pyro_model=sequence_model,
    kernel=SequenceMetropolis,
    evidence=SequenceEvidence,
    site_shapes=site_shapes,
    nuts_sites=nuts_sites,
    sample_streams=sample_streams,
    sequences=True,
    correlated_frames=True,
    filter_draws=2000,  # a draw costs M - 1 times the paper's (benchmarks/bench_fit_scale.py: a frame within its 2 ms floor)
    point_estimate=lambda draws: {k: v.mean(0, keepdim=True) for k, v in draws.items()},
    free_entry=lambda site, index: site not in COVARIANCES or index[-2] <= index[-1],
    positive_sites=("between_pooling",),
    arviz_dims={
        "loc": ["class", "coord"],
        "between": ["class", "coord", "coord_to"],
        "between_mean": ["coord", "coord_to"],
        "within": ["coord", "coord_to"],
    },
    draw_prior=draw_prior,
    simulate=simulate,
    rank_statistics=rank_statistics,
    hyperprior_fields=(
        "look_vertex",
        "look_sd",
        "between_scale",
        "between_df",
        "between_pooling_median",
        "between_pooling_sd",
        "within_scale",
        "within_df",
    ),
    unit_log_lik=sequence_unit_log_lik,
    log_prior=sequence_prior_log_prob,
    mh_sites=("between_pooling",),
)

__all__ = [
    "NOISE_MODEL",
    "SequenceEvidence",
    "SequenceMetropolis",
    "SequenceStats",
    "ShiftPrior",
    "estimate_frame_correlation",
    "sample_sequences",
    "sequence_log_joint",
    "sequence_model",
    "sequence_stats",
]
