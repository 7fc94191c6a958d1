"""The confusion-aware model: ``o | c ~ Dir(theta_c e_c + beta_c)``, a full concentration vector per class under
a prior that shrinks it towards the paper's, as one :class:`NoiseModel`.

Its room holds the Pyro program (:mod:`.program`), the MH kernel (:mod:`.kernel`, its steps in :mod:`.steps`; the
class move and the ``(kappa, gamma)`` move are the paper's) and the filter's evidence (:mod:`.evidence`). It
treats a sequence's frames as independent, and its per-class confusion vectors make each frame sharper evidence
than the paper's model does, so on correlated frames its confidence compounds fastest of the three; a fitted
temper (:func:`hbni_pyro.fit_temper`) helps at moderate thresholds only (docs/noise_models.md measures it). On
camera sequences use the sequence model; use this one untempered only on i.i.d. outputs.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.density import concentrations
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import sample_dirichlet
from hbni_pyro.models.confusion.evidence import ConfusionEvidence
from hbni_pyro.models.confusion.kernel import ConfusionMetropolis
from hbni_pyro.models.confusion.program import confusion_log_joint, confusion_model, off_diagonal
from hbni_pyro.models.paper import PAPER_HYPERPRIOR, concentration_prior, concentration_statistics
from hbni_pyro.models.spec import Draws, NoiseModel
from hbni_pyro.validation import DTYPE

SCALARS = ("kappa", "gamma", "beta_loc", "beta_scale")


def site_shapes(num_classes: int) -> dict[str, tuple[int, ...]]:
    M = num_classes
    return {"theta": (M,), "beta": (M, M), "kappa": (), "gamma": (), "beta_loc": (), "beta_scale": ()}


def nuts_sites(raw: Draws) -> Draws:
    beta = off_diagonal((raw["beta_loc"][..., None, None] + raw["beta_scale"][..., None, None] * raw["beta_raw"]).exp())
    return {"theta": raw["theta"], "beta": beta, **{k: raw[k] for k in SCALARS}}


def sample_streams(draws: Draws, true_class: int, num_frames: int, generator: torch.Generator) -> Tensor:
    alpha = concentrations(draws["theta"], draws["beta"])[:, true_class]
    return sample_dirichlet(alpha.unsqueeze(1).expand(alpha.shape[0], num_frames, -1), generator)


def draw_prior(hyperprior: HyperPrior, num_classes: int, num_draws: int, generator: torch.Generator) -> Draws:
    h, n, M, g = hyperprior, num_draws, num_classes, generator
    out = concentration_prior(h, M, n, g)
    loc = h.offdiag_loc_sd * torch.randn(n, generator=g, dtype=DTYPE)
    scale = h.offdiag_scale_sd * torch.randn(n, generator=g, dtype=DTYPE).abs()
    log_beta = loc[:, None, None] + scale[:, None, None] * torch.randn(n, M, M, generator=g, dtype=DTYPE)
    out.update(beta=log_beta.exp().masked_fill(torch.eye(M, dtype=torch.bool), 1.0), beta_loc=loc, beta_scale=scale)
    return out


def simulate(params: Draws, classes: Tensor, num_frames: int, generator: torch.Generator) -> Tensor:
    return sample_dirichlet(concentrations(params["theta"], params["beta"])[classes], generator)


def rank_statistics(params: Draws) -> dict[str, Tensor]:
    stats = concentration_statistics(params)
    off = ~torch.eye(params["beta"].shape[-1], dtype=torch.bool)
    stats.update(
        {
            "log beta[0, 1]": params["beta"][:, 0, 1].log(),
            "log beta[2, 0]": params["beta"][:, 2, 0].log(),
            "mean log beta": params["beta"][:, off].log().mean(-1),
            "beta_loc": params["beta_loc"],
            "beta_scale": params["beta_scale"],
        }
    )
    return stats


NOISE_MODEL = NoiseModel(
    name="confusion",
    summary="o | c ~ Dir(theta_c e_c + beta_c), a concentration vector per class",
    pyro_model=confusion_model,
    kernel=ConfusionMetropolis,
    evidence=ConfusionEvidence,
    site_shapes=site_shapes,
    nuts_sites=nuts_sites,
    sample_streams=sample_streams,
    max_plate_nesting=2,
    free_entry=lambda site, index: site != "beta" or index[0] != index[1],
    positive_sites=("theta", "beta", "kappa", "gamma", "beta_scale"),
    arviz_dims={"theta": ["class"], "beta": ["class", "class_to"]},
    draw_prior=draw_prior,
    simulate=simulate,
    rank_statistics=rank_statistics,
    hyperprior_fields=(*PAPER_HYPERPRIOR, "offdiag_loc_sd", "offdiag_scale_sd"),
)

__all__ = ["NOISE_MODEL", "ConfusionEvidence", "ConfusionMetropolis", "confusion_log_joint", "confusion_model"]
