"""``HyperPrior``: the hyperparameters of every noise model's prior, one record for all of them.

Gammas are shape-scale (``Ga(k, s)``, mean ``k s``); each noise model reads its own fields
(:attr:`hbni_pyro.NoiseModel.hyperprior_fields`) and ignores the others.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class HyperPrior:
    """Hyperparameters of every noise model (each model reads its own fields).

    Paper's model (and the confusion-aware model's lifts): shape-scale
    ``kappa ~ Ga(beta, eta)``, ``gamma ~ Ga(nu, omega)``, ``theta_m ~ Ga(kappa, gamma)``. The defaults
    put the prior mean of kappa at 2 and of gamma at 10, so the implied prior on each ``theta_m``
    has mean 20, median about 10 and a 90 % range of about 0.16 to 73: from a class whose outputs
    are nearly uniform on the simplex to a near-perfect one, a weakly informative prior over the
    whole range a CNN's per-class noise can take.

    Confusion-aware model: off-diagonal concentrations ``log beta_cj ~ N(beta_loc, beta_scale^2)``
    with ``beta_loc ~ N(0, offdiag_loc_sd^2)`` and ``beta_scale ~ HalfNormal(offdiag_scale_sd)``.
    The prior is centred on the paper's ``beta_cj = 1`` and shrinks all confusions towards one
    shared level; its defaults (0.5, 0.5) keep the model within one frame of the paper's on the
    paper's toy (15 unlabelled outputs), where wider ones (2, 1) let some training sets explain a noisy
    class by confusions and the error stalls above the paper's (``experiment=noise_models``).

    Sequence-aware model, on the ``d = M - 1`` log-ratio coordinates of an output:
    class means ``m_c ~ N(look_vertex * u_c, look_sd^2 I)`` (``u_c`` the unit direction of vertex
    ``c``: the prior says class c's outputs lean towards class c). The spread of a class's sequence
    looks ``B_c ~ InvWishart(lam + d + 1, lam B)`` is pooled towards a shared
    ``B ~ Wishart(d + between_df, between_scale / (d + between_df) I)`` (mean ``between_scale I``) with
    ``lam ~ LogNormal(log between_pooling_median, between_pooling_sd)``, worth that many pseudo-sequences.
    Frames scatter around their look with one covariance for all classes,
    ``W ~ InvWishart(d + 1 + within_df, within_df * within_scale * I)`` (mean ``within_scale I``).
    The defaults expect looks to differ little between sequences (``between_scale`` 0.2 against
    ``within_scale`` 0.5) and class means near their vertex (``look_sd`` 1): with the toy's three
    unlabelled training sequences the data cannot tell these apart, and a wider prior (0.5, 2)
    both swaps classes in some fits and lets the evidence saturate too early (the toy's error target is
    never reached). Mission data (tens of labelled sequences per class) outweigh them.
    """

    beta: float = 2.0
    eta: float = 1.0
    nu: float = 2.0
    omega: float = 5.0
    offdiag_loc_sd: float = 0.5
    offdiag_scale_sd: float = 0.5
    look_vertex: float = 1.5
    look_sd: float = 1.0
    between_scale: float = 0.2
    between_df: float = 2.0
    between_pooling_median: float = 10.0
    between_pooling_sd: float = 1.0
    within_scale: float = 0.5
    within_df: float = 2.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and value > 0 and value < float("inf")):
                raise ValueError(f"HyperPrior.{name}: expected a positive finite number, got {value!r}")

    @classmethod
    def near_perfect(cls) -> "HyperPrior":
        """A confident prior that the classifier is near-perfect: prior median theta about 100."""
        return cls(beta=20.0, eta=0.25, nu=20.0, omega=1.1)

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}
