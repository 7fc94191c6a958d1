"""Noise models with known parameters and the data the model tests draw from them: the paper's toy
(``toy_obs``), a known confusion structure (``confusion_data``) and known sequence looks (``sequences``)."""

import torch

import hbni_pyro
from hbni_pyro import sample_dirichlet, sample_outputs, sample_sequences

DT = torch.float64
THETA = torch.tensor([1.0, 6.0, 20.0], dtype=DT)
"""The paper toy's per-class concentrations: class 0 is noise, class 2 nearly clean."""
CLASSES = torch.arange(3).repeat_interleave(5)


def toy_obs(seed: int) -> torch.Tensor:
    """``(15, 3)`` outputs of the paper's toy, five per class."""
    return sample_outputs(THETA, CLASSES, torch.Generator().manual_seed(seed))


ALPHA = torch.tensor([[5.0, 2.0, 0.4], [0.6, 9.0, 0.5], [0.3, 0.3, 4.0]], dtype=DT)
"""A known confusion structure: class 0 leans towards class 1, class 2 is clean."""
LOC = torch.tensor([[1.2, 0.1], [-0.7, 1.0], [-0.6, -1.1]], dtype=DT)


def confusion_params():
    theta = ALPHA.diagonal() - 1
    beta = ALPHA.clone()
    beta.diagonal().fill_(1.0)
    return {
        "theta": theta,
        "beta": beta,
        "kappa": torch.tensor(1.5, dtype=DT),
        "gamma": torch.tensor(4.0, dtype=DT),
        "beta_loc": torch.tensor(-0.3, dtype=DT),
        "beta_scale": torch.tensor(0.8, dtype=DT),
    }


def sequence_params():
    between = torch.stack(
        [
            torch.tensor([[0.3, 0.05], [0.05, 0.2]]),
            torch.tensor([[0.25, 0.0], [0.0, 0.35]]),
            torch.tensor([[0.2, -0.05], [-0.05, 0.3]]),
        ]
    ).to(DT)
    return {
        "loc": LOC,
        "between": between,
        "between_mean": torch.tensor([[0.3, 0.0], [0.0, 0.3]], dtype=DT),
        "between_pooling": torch.tensor(8.0, dtype=DT),
        "within": torch.tensor([[0.4, 0.1], [0.1, 0.5]], dtype=DT),
    }


def sequences(num_seq=9, frames=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    p = sequence_params()
    classes = torch.arange(3).repeat_interleave(num_seq // 3)
    obs = sample_sequences(p["loc"], p["between"], p["within"], classes, frames, g)
    return obs, classes


def confusion_data(n_per_class=10, seed=0):
    g = torch.Generator().manual_seed(seed)
    classes = torch.arange(3).repeat_interleave(n_per_class)
    return hbni_pyro.as_outputs(sample_dirichlet(ALPHA[classes], g)), classes
