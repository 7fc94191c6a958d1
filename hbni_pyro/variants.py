"""The noise-model variants by name, and the shape of each of their posterior sites.

- ``paper``: ``o | c ~ Dir(theta_c e_c + 1)`` (:mod:`hbni_pyro.model`), the default.
- ``confusion``: ``o | c ~ Dir(theta_c e_c + beta_c)``, a full concentration vector per class
  under a prior that shrinks it towards the paper's (:mod:`hbni_pyro.confusion_model`).
- ``sequence``: a latent look per sequence, so a sequence's frames are exchangeable
  (:mod:`hbni_pyro.sequence_model`); its fits take sequence ids.
"""

from __future__ import annotations

MODELS = ("paper", "confusion", "sequence")
SEQUENCE_MODELS = ("sequence",)
"""Variants whose fits need sequence ids."""


def check_model(model: object) -> str:
    """Return ``model`` if it names a variant, else raise a ``ValueError`` listing them."""
    if model not in MODELS:
        raise ValueError(f"model: expected one of {MODELS}, got {model!r}")
    return str(model)


def site_shapes(model: str, num_classes: int) -> dict[str, tuple[int, ...]]:
    """Per-draw shape of every posterior site of ``model`` with ``M = num_classes``."""
    M, d = num_classes, num_classes - 1
    if model == "paper":
        return {"theta": (M,), "kappa": (), "gamma": ()}
    if model == "confusion":
        return {"theta": (M,), "beta": (M, M), "kappa": (), "gamma": (), "beta_loc": (), "beta_scale": ()}
    if model == "sequence":
        return {"loc": (M, d), "between": (M, d, d), "between_mean": (d, d), "between_pooling": (), "within": (d, d)}
    raise ValueError(f"model: expected one of {MODELS}, got {model!r}")
