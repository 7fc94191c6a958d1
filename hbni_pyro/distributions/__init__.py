"""What every noise model is written in: the hyperprior, the closed-form log densities and the seeded samplers.

- :mod:`.prior`: :class:`HyperPrior`, the hyperparameters of every model's prior.
- :mod:`.density`: the Dirichlet block likelihood all frame-level models share, shape-scale gammas, normals, the
  simplex's log-ratio coordinates, and Pyro distributions over outputs.
- :mod:`.sampling`: gamma, Dirichlet and Gaussian draws from an explicit ``torch.Generator``.
- :mod:`.draws`: the evidence's average over posterior draws, in log space and in a fixed order.
"""

from hbni_pyro.distributions.density import (
    DirichletOutputs,
    IlrNormalOutputs,
    assigned_log_lik,
    class_log_lik,
    concentrations,
    gamma_log_prob,
    helmert_basis,
    ilr,
    ilr_log_jacobian,
    lifted_dirichlet_log_prob,
    lifted_normaliser,
    normal_log_prob,
)
from hbni_pyro.distributions.draws import logsumexp_in_order
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.distributions.sampling import MAX_ROUNDS, gamma_variates, sample_dirichlet, sample_gamma, sample_gaussian

__all__ = [
    "MAX_ROUNDS",
    "DirichletOutputs",
    "HyperPrior",
    "IlrNormalOutputs",
    "assigned_log_lik",
    "class_log_lik",
    "concentrations",
    "gamma_log_prob",
    "gamma_variates",
    "helmert_basis",
    "ilr",
    "ilr_log_jacobian",
    "lifted_dirichlet_log_prob",
    "lifted_normaliser",
    "logsumexp_in_order",
    "normal_log_prob",
    "sample_dirichlet",
    "sample_gamma",
    "sample_gaussian",
]
