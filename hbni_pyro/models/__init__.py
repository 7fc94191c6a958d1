"""The noise-model variants, by name.

- ``paper``: ``o | c ~ Dir(theta_c e_c + 1)`` (:mod:`hbni_pyro.model`), the default of the library.
- ``confusion``: ``o | c ~ Dir(theta_c e_c + beta_c)``, a full concentration vector per class
  under a prior that shrinks it towards the paper's (:mod:`hbni_pyro.confusion_model`).
- ``sequence``: a latent look per sequence, so a sequence's frames are exchangeable
  (:mod:`hbni_pyro.sequence_model`); its fits take sequence ids.

Each is a :class:`NoiseModel` in its own module. A new variant is one module that builds a
``NoiseModel`` and one :func:`register` call (or one line in :data:`NOISE_MODELS`).
"""

from __future__ import annotations

from hbni_pyro.variants import confusion, paper, sequence
from hbni_pyro.variants.spec import NoiseModel

NOISE_MODELS: dict[str, NoiseModel] = {
    spec.name: spec for spec in (paper.NOISE_MODEL, confusion.NOISE_MODEL, sequence.NOISE_MODEL)
}
"""The registered variants, name -> spec."""
_BUILT_IN = tuple(NOISE_MODELS)


def model_names() -> tuple[str, ...]:
    """The names of the registered variants, in registration order."""
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
    """Remove the variant ``name`` (for tests and interactive work); the built-in variants stay."""
    if name in _BUILT_IN:
        raise ValueError(f"name: the built-in noise model {name!r} cannot be removed")
    noise_model(name)
    del NOISE_MODELS[name]


def site_shapes(model: str, num_classes: int) -> dict[str, tuple[int, ...]]:
    """Per-draw shape of every posterior site of ``model`` with ``M = num_classes``."""
    return noise_model(model).site_shapes(num_classes)


__all__ = [
    "NOISE_MODELS",
    "NoiseModel",
    "check_model",
    "model_names",
    "noise_model",
    "register",
    "site_shapes",
    "unregister",
]
