"""The prior of a sequence model adapted to a new place: its class looks are the old place's, moved together.

At a new place (other light, weather, camera) every class's outputs move, and they mostly move *together*: a
darker scene makes the classifier less sure of every class and pulls its errors towards the same few classes.
A sequence model fitted at the old place gives each class's mean look ``a_c`` (log-ratio coordinates,
:mod:`hbni_pyro.models.sequence.program`); at the new place

    m_c ~ N(s a_c + b, shift_sd^2 I)     s ~ N(1, scale_sd^2),  b ~ N(0, offset_sd^2 I)

a shared scale ``s`` (below 1: less confident outputs) and offset ``b`` (towards the classes the new place's
frames are mistaken for) move every class, and each class deviates from that by ``shift_sd`` per coordinate.
The shared part is learnt from the new place's frames, labelled or not; the small per-class part is what keeps an
unlabelled fit identifiable: each cluster of new-place sequences stays the class whose old look, moved, lies
nearest, instead of any class the clusters could be permuted into. Measured between the mission's conditions and
a darker, noisier place with stronger colour casts (48 labelled sequences per class at each), the per-class
deviation after the shared move was 0.15-0.44 in norm over the ``d = 5`` coordinates: about 0.1-0.2 per
coordinate, hence the default ``shift_sd = 0.2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from hbni_pyro.validation import DTYPE
from hbni_infra.checks import as_float, as_names


@dataclass(frozen=True)
class ShiftPrior:
    """Class means ``m_c ~ N(s anchor_c + b, shift_sd^2 I)``, ``s ~ N(1, scale_sd^2)``, ``b ~ N(0, offset_sd^2 I)``.

    Attributes:
        anchor: ``(M, d)`` the old place's class mean looks (``d = M - 1`` log-ratio coordinates).
        class_names: the classes' names in the anchor's row order (``None``: unnamed).
        shift_sd: how far one class may move apart from the shared move, per coordinate.
        scale_sd, offset_sd: the prior spread of the shared scale (about 1) and offset (about 0).
    """

    anchor: Tensor
    class_names: tuple[str, ...] | None = None
    shift_sd: float = 0.2
    scale_sd: float = 0.3
    offset_sd: float = 1.0

    def __post_init__(self) -> None:
        anchor = torch.as_tensor(self.anchor)
        if not anchor.is_floating_point() or anchor.dim() != 2 or anchor.shape[0] < 2:
            raise ValueError(
                f"anchor: expected a float (M, M - 1) tensor of class looks with M >= 2, got {tuple(anchor.shape)}"
            )
        if anchor.shape[1] != anchor.shape[0] - 1:
            raise ValueError(f"anchor: expected shape (M, M - 1), got {tuple(anchor.shape)}")
        if not bool(torch.isfinite(anchor).all()):
            raise ValueError("anchor: expected finite class looks, got NaN or infinite ones")
        object.__setattr__(self, "anchor", anchor.to(DTYPE))
        object.__setattr__(self, "class_names", as_names("class_names", self.class_names, anchor.shape[0]))
        for name in ("shift_sd", "scale_sd", "offset_sd"):
            object.__setattr__(self, name, as_float(name, getattr(self, name), 0.0, low_open=True, high_open=True))

    @classmethod
    def from_posterior(cls, posterior: Any, **spreads: float) -> ShiftPrior:
        """The prior anchored at a fitted sequence-model posterior's mean class looks (and named as it is);
        ``spreads``: ``shift_sd``, ``scale_sd``, ``offset_sd``."""
        if getattr(posterior, "model", None) != "sequence":
            raise ValueError(
                f"posterior: expected a fitted 'sequence' model posterior, got model {getattr(posterior, 'model', None)!r}"
            )
        return cls(posterior.draws()["loc"].mean(0).cpu(), posterior.class_names, **spreads)

    @property
    def num_classes(self) -> int:
        return int(self.anchor.shape[0])

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable (stored in an adapted posterior's ``info``)."""
        return {
            "anchor": self.anchor.tolist(),
            "class_names": None if self.class_names is None else list(self.class_names),
            "shift_sd": self.shift_sd,
            "scale_sd": self.scale_sd,
            "offset_sd": self.offset_sd,
        }
