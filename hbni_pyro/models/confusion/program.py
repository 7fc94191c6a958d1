"""The confusion-aware noise model: a full concentration vector per class, shrunk towards the paper's.

    kappa, gamma, theta_m           as in the paper's model (``theta_m ~ Ga(kappa, gamma)``)
    beta_loc   ~ N(0, offdiag_loc_sd^2)          shared level of the confusions (0: the paper's 1)
    beta_scale ~ HalfNormal(offdiag_scale_sd)    how much the confusions differ from that level
    log beta_cj ~ N(beta_loc, beta_scale^2)      c != j: class c's outputs' pull towards class j
    o_i | c_i = c ~ Dir(theta_c e_c + beta_c)    beta_cc = 1

Every class has its own pattern of confusions (medical and news copters pull towards each
other, crates do not). With all ``beta_cj = 1`` it is exactly the paper's model, and the
hierarchical prior shrinks the confusions towards one shared level, so with little data (or
uniform confusions) it stays close to the paper's structure.

The Pyro program samples the off-diagonal ``beta`` non-centred (``beta_raw ~ N(0, 1)``), which
NUTS explores better; :func:`off_diagonal` places ``(M, M - 1)`` values around a unit diagonal.
"""

from __future__ import annotations

import pyro
import pyro.distributions as dist
import torch
from torch import Tensor

from hbni_pyro.distributions.density import class_log_lik, concentrations, gamma_log_prob, normal_log_prob
from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.models.paper.program import observe_outputs


def off_diagonal(values: Tensor, fill: float = 1.0) -> Tensor:
    """``(..., M, M - 1)`` off-diagonal entries, row by row -> ``(..., M, M)`` with ``fill`` on the diagonal."""
    num_classes = values.shape[-2]
    out = torch.full(values.shape[:-2] + (num_classes, num_classes), fill, dtype=values.dtype)
    mask = ~torch.eye(num_classes, dtype=torch.bool)
    out[..., mask] = values.reshape(values.shape[:-2] + (-1,))
    return out


def off_diagonal_values(matrix: Tensor) -> Tensor:
    """Inverse of :func:`off_diagonal`: ``(..., M, M)`` -> ``(..., M, M - 1)``."""
    num_classes = matrix.shape[-1]
    mask = ~torch.eye(num_classes, dtype=torch.bool)
    return matrix[..., mask].reshape(matrix.shape[:-2] + (num_classes, num_classes - 1))


def confusion_model(
    obs: Tensor,
    labels: Tensor | None = None,
    class_prior: Tensor | None = None,
    hyperprior: HyperPrior = HyperPrior(),
) -> None:
    """Pyro model of ``N`` outputs ``obs (N, M)`` with optional ``labels (N,)`` (-1 = unknown).

    Unknown classes are enumerated in parallel (``max_plate_nesting=2``: the ``rows x cols``
    plates of ``beta_raw``). Inputs must already be validated.
    """
    num_classes = obs.shape[1]
    p = class_prior if class_prior is not None else obs.new_full((num_classes,), 1.0 / num_classes)
    h = hyperprior
    kappa = pyro.sample("kappa", dist.Gamma(obs.new_tensor(h.beta), obs.new_tensor(1.0 / h.eta)))
    gamma = pyro.sample("gamma", dist.Gamma(obs.new_tensor(h.nu), obs.new_tensor(1.0 / h.omega)))
    with pyro.plate("classes", num_classes, dim=-1):
        theta = pyro.sample("theta", dist.Gamma(kappa, 1.0 / gamma))
    beta_loc = pyro.sample("beta_loc", dist.Normal(obs.new_tensor(0.0), obs.new_tensor(h.offdiag_loc_sd)))
    beta_scale = pyro.sample("beta_scale", dist.HalfNormal(obs.new_tensor(h.offdiag_scale_sd)))
    with pyro.plate("rows", num_classes, dim=-2), pyro.plate("cols", num_classes - 1, dim=-1):
        beta_raw = pyro.sample("beta_raw", dist.Normal(obs.new_tensor(0.0), obs.new_tensor(1.0)))
    beta = off_diagonal((beta_loc + beta_scale * beta_raw).exp())
    observe_outputs(obs, labels, p, concentrations(theta, beta))


def confusion_prior_log_prob(
    theta: Tensor,
    beta: Tensor,
    kappa: Tensor,
    gamma: Tensor,
    beta_loc: Tensor,
    beta_scale: Tensor,
    hyperprior: HyperPrior,
) -> Tensor:
    """``log p(theta, beta, kappa, gamma, beta_loc, beta_scale)`` with the density over ``beta`` itself
    (not its log), batched over leading dims: theta ``(..., M)``, beta ``(..., M, M)``, the rest ``(...)``."""
    h = hyperprior
    lp = gamma_log_prob(kappa, h.beta, h.eta) + gamma_log_prob(gamma, h.nu, h.omega)
    lp = lp + gamma_log_prob(theta, kappa.unsqueeze(-1), gamma.unsqueeze(-1)).sum(-1)
    lp = lp + normal_log_prob(beta_loc, 0.0, h.offdiag_loc_sd)
    lp = lp + normal_log_prob(beta_scale, 0.0, h.offdiag_scale_sd) + torch.log(torch.tensor(2.0, dtype=theta.dtype))
    log_b = off_diagonal_values(beta).log()
    lp = lp + (normal_log_prob(log_b, beta_loc[..., None, None], beta_scale[..., None, None]) - log_b).sum((-1, -2))
    return lp


def confusion_log_joint(
    obs: Tensor,
    params: dict[str, Tensor],
    labels: Tensor | None = None,
    class_prior: Tensor | None = None,
    hyperprior: HyperPrior = HyperPrior(),
) -> Tensor:
    """``log p(obs, known labels, params)`` with unknown classes summed out, in closed form.

    ``params`` holds ``theta (..., M)``, ``beta (..., M, M)``, ``kappa``, ``gamma``, ``beta_loc``,
    ``beta_scale`` ``(...)``. Returns ``(...)``.
    """
    num_obs, num_classes = obs.shape
    p = class_prior if class_prior is not None else obs.new_full((num_classes,), 1.0 / num_classes)
    lp = confusion_prior_log_prob(
        params["theta"],
        params["beta"],
        params["kappa"],
        params["gamma"],
        params["beta_loc"],
        params["beta_scale"],
        hyperprior,
    )
    per_class = class_log_lik(1.0, obs.log(), params["theta"], params["beta"]) + p.log()  # (..., N, M)
    labels = torch.full((num_obs,), -1, dtype=torch.long) if labels is None else labels
    known = labels >= 0
    fixed = per_class[..., known, :].gather(-1, labels[known].expand(per_class.shape[:-2] + (-1,)).unsqueeze(-1))
    return lp + torch.logsumexp(per_class[..., ~known, :], -1).sum(-1) + fixed.squeeze(-1).sum(-1)
