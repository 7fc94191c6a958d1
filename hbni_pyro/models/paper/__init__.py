"""The paper's model: ``o | c ~ Dir(theta_c e_c + 1)`` under a shared Gamma hyperprior, as one :class:`NoiseModel`.

Its room holds the Pyro program (:mod:`.program`), the output sampler (:mod:`.sampler`), the MH kernel
(:mod:`.kernel`, its steps in :mod:`.steps`; the class move is the frame-level kernels' shared one,
:mod:`hbni_pyro.mcmc.class_moves`) and the filter's evidence (:mod:`.evidence`). It treats a sequence's frames as
independent, so on correlated frames (one camera sequence) its confidence compounds too fast: use it there with
the fitted temper (:func:`hbni_pyro.fit_temper`), or use the sequence model (docs/noise_models.md measures both).
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import gamma_variates
from hbni_pyro.models.paper.evidence import PaperEvidence
from hbni_pyro.models.paper.kernel import HBNIMetropolis
from hbni_pyro.models.paper.program import hbni_model, log_joint, prior_theta_log_density
from hbni_pyro.models.paper.sampler import sample_outputs
from hbni_pyro.models.spec import Draws, NoiseModel

SITES = ("theta", "kappa", "gamma")


def site_shapes(num_classes: int) -> dict[str, tuple[int, ...]]:
    return {"theta": (num_classes,), "kappa": (), "gamma": ()}


def concentration_prior(hyperprior: HyperPrior, num_classes: int, num_draws: int, generator: torch.Generator) -> Draws:
    """``theta``, ``kappa``, ``gamma`` from the prior ``(n, ...)``; the confusion model shares them."""
    h, n, g = hyperprior, num_draws, generator
    kappa = gamma_variates(torch.full((n,), h.beta), h.eta, g)
    gamma = gamma_variates(torch.full((n,), h.nu), h.omega, g)
    return {
        "theta": gamma_variates(kappa.unsqueeze(-1).expand(n, num_classes), gamma.unsqueeze(-1), g),
        "kappa": kappa,
        "gamma": gamma,
    }


def concentration_statistics(params: Draws) -> dict[str, Tensor]:
    """``log theta[m]``, ``log kappa``, ``log gamma`` per draw, the ranks SBC checks."""
    stats = {f"log theta[{m}]": params["theta"][:, m].log() for m in range(params["theta"].shape[1])}
    stats.update({"log kappa": params["kappa"].log(), "log gamma": params["gamma"].log()})
    return stats


def sample_streams(draws: Draws, true_class: int, num_frames: int, generator: torch.Generator) -> Tensor:
    theta = draws["theta"]
    classes = torch.full((theta.shape[0], num_frames), true_class, dtype=torch.long, device=theta.device)
    return sample_outputs(theta.unsqueeze(1), classes, generator)


def simulate(params: Draws, classes: Tensor, num_frames: int, generator: torch.Generator) -> Tensor:
    return sample_outputs(params["theta"], classes, generator)


#: the hyperprior fields of the paper's model (kappa's and gamma's Gamma priors)
PAPER_HYPERPRIOR = ("beta", "eta", "nu", "omega")

NOISE_MODEL = NoiseModel(
    name="paper",
    summary="o | c ~ Dir(theta_c e_c + 1), the paper's model",
    pyro_model=hbni_model,
    kernel=HBNIMetropolis,
    evidence=PaperEvidence,
    site_shapes=site_shapes,
    nuts_sites=lambda raw: {k: raw[k] for k in SITES},
    sample_streams=sample_streams,
    positive_sites=SITES,
    arviz_dims={"theta": ["class"]},
    draw_prior=concentration_prior,
    simulate=simulate,
    rank_statistics=concentration_statistics,
    hyperprior_fields=PAPER_HYPERPRIOR,
)

__all__ = [
    "NOISE_MODEL",
    "HBNIMetropolis",
    "PaperEvidence",
    "hbni_model",
    "log_joint",
    "prior_theta_log_density",
    "sample_outputs",
]
