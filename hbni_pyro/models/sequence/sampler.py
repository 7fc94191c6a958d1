"""Output sequences drawn from the sequence-aware model with an explicit ``torch.Generator``."""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro.distributions.density import helmert_basis
from hbni_pyro.distributions.sampling import as_classes, sample_gaussian, to_gaussian
from hbni_pyro.models.sequence.correlation import ar1_normals
from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float, as_int


def sample_sequences(
    loc: Tensor,
    between: Tensor,
    within: Tensor,
    classes: Tensor,
    num_frames: int,
    generator: torch.Generator,
    correlation: float = 0.0,
) -> Tensor:
    """Output sequences from the sequence-aware model: ``(K, num_frames, M)`` for ``classes (K,)``.

    Each sequence draws its look ``mu_k ~ N(loc[c_k], between[c_k])``, then its frames'
    log-ratio coordinates ``y ~ N(mu_k, within)``, mapped to the simplex by ``softmax(H^T y)``.
    ``loc (M, d)``, ``between (M, d, d)``, ``within (d, d)`` (or ``(K, 1, d, d)``: one per sequence).
    With ``correlation`` (in (-1, 1)) the frames' scatter about the look is an AR(1) series with that lag-1
    correlation (:mod:`hbni_pyro.models.sequence.correlation`); 0 draws them i.i.d.
    """
    classes = as_classes(classes, loc.shape[0], loc.device)
    num_frames = as_int("num_frames", num_frames, minimum=1)
    correlation = as_float("correlation", correlation, -1.0, 1.0, low_open=True, high_open=True)
    look = sample_gaussian(loc[classes], between[classes], generator)
    z = ar1_normals(look.shape[:-1] + (num_frames, look.shape[-1]), correlation, generator, look.device)
    y = to_gaussian(look.unsqueeze(-2), within, z)
    return torch.softmax(y @ helmert_basis(loc.shape[-1] + 1, DTYPE, loc.device), -1).clamp_min(torch.finfo(DTYPE).tiny)
