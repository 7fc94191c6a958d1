"""A toy noise-model variant, written as a user would add one: this module plus one ``register`` call.

``frozen``: the paper's per-output model, but the camera never moves, so a stream repeats one
output. Fitting and filtering are the paper's (its kernel, Pyro program and evidence); the
predictive streams are its own.
"""

from __future__ import annotations

import torch
from torch import Tensor

from hbni_pyro import HBNIMetropolis, NoiseModel, hbni_model
from hbni_pyro.models import PaperEvidence, paper


def sample_streams(draws: dict[str, Tensor], true_class: int, num_frames: int, generator: torch.Generator) -> Tensor:
    one = paper.sample_streams(draws, true_class, 1, generator)
    return one.expand(-1, num_frames, -1).clone()


NOISE_MODEL = NoiseModel(
    name="frozen",
    summary="the paper's model, one output repeated over a stream",
    pyro_model=hbni_model,
    kernel=HBNIMetropolis,
    evidence=PaperEvidence,
    site_shapes=paper.site_shapes,
    nuts_sites=paper.NOISE_MODEL.nuts_sites,
    sample_streams=sample_streams,
)
