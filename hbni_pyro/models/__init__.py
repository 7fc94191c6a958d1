"""The noise models, by name: each one a :class:`NoiseModel` record in its own room.

- ``paper`` (:mod:`hbni_pyro.models.paper`): ``o | c ~ Dir(theta_c e_c + 1)``, the default of the library.
- ``confusion`` (:mod:`hbni_pyro.models.confusion`): ``o | c ~ Dir(theta_c e_c + beta_c)``, a full concentration
  vector per class under a prior that shrinks it towards the paper's.
- ``sequence`` (:mod:`hbni_pyro.models.sequence`): a latent look per sequence, so a sequence's frames are
  exchangeable; its fits take sequence ids.

A model's room holds its Pyro program, generative sampler, MH kernel and steps and the filter's evidence; what
several models share lies below them (:mod:`hbni_pyro.distributions`, :mod:`hbni_pyro.mcmc`). A new model is one
room that builds a ``NoiseModel`` and one :func:`register` call (or one line in :data:`NOISE_MODELS`).
"""

from __future__ import annotations

from hbni_pyro.models import confusion, paper, sequence
from hbni_pyro.models.confusion import ConfusionEvidence, ConfusionMetropolis, confusion_model
from hbni_pyro.models.paper import HBNIMetropolis, PaperEvidence, hbni_model, log_joint, sample_outputs
from hbni_pyro.models.sequence import (
    SequenceEvidence,
    SequenceMetropolis,
    SequenceStats,
    ShiftPrior,
    estimate_frame_correlation,
    sample_sequences,
    sequence_model,
    sequence_stats,
)
from hbni_pyro.models.spec import Draws, NoiseModel

NOISE_MODELS: dict[str, NoiseModel] = {
    spec.name: spec for spec in (paper.NOISE_MODEL, confusion.NOISE_MODEL, sequence.NOISE_MODEL)
}
"""The registered noise models, name -> record."""
_BUILT_IN = tuple(NOISE_MODELS)


def model_names() -> tuple[str, ...]:
    """The names of the registered noise models, in registration order."""
    return tuple(NOISE_MODELS)


def noise_model(model: object) -> NoiseModel:
    """The registered variant called ``model`` (or ``model`` itself if it is a registered spec)."""
    if isinstance(model, NoiseModel) and NOISE_MODELS.get(model.name) is model:
        return model
    if not isinstance(model, str) or model not in NOISE_MODELS:
        raise ValueError(f"model: expected one of {model_names()}, got {model!r}")
    return NOISE_MODELS[model]


def check_model(model: object) -> str:
    """The name of the registered variant ``model`` names, else a ``ValueError`` listing them."""
    return noise_model(model).name


def register(spec: NoiseModel) -> NoiseModel:
    """Add ``spec`` under ``spec.name``; a name already taken by another spec raises ``ValueError``."""
    if not isinstance(spec, NoiseModel):
        raise TypeError(f"spec: expected a NoiseModel, got {type(spec).__name__}")
    if not spec.name.isidentifier():
        raise ValueError(f"spec.name: expected an identifier, got {spec.name!r}")
    if NOISE_MODELS.get(spec.name, spec) is not spec:
        raise ValueError(f"spec.name: a noise model called {spec.name!r} is already registered")
    NOISE_MODELS[spec.name] = spec
    return spec


def unregister(name: str) -> None:
    """Remove the noise model ``name`` (for tests and interactive work); the built-in models stay."""
    if name in _BUILT_IN:
        raise ValueError(f"name: the built-in noise model {name!r} cannot be removed")
    noise_model(name)
    del NOISE_MODELS[name]


def site_shapes(model: str, num_classes: int) -> dict[str, tuple[int, ...]]:
    """Per-draw shape of every posterior site of ``model`` with ``M = num_classes``."""
    return noise_model(model).site_shapes(num_classes)


__all__ = [
    "NOISE_MODELS",
    "ConfusionEvidence",
    "ConfusionMetropolis",
    "Draws",
    "HBNIMetropolis",
    "NoiseModel",
    "PaperEvidence",
    "SequenceEvidence",
    "SequenceMetropolis",
    "SequenceStats",
    "ShiftPrior",
    "check_model",
    "confusion_model",
    "estimate_frame_correlation",
    "hbni_model",
    "log_joint",
    "model_names",
    "noise_model",
    "register",
    "sample_outputs",
    "sample_sequences",
    "sequence_model",
    "sequence_stats",
    "site_shapes",
    "unregister",
]
