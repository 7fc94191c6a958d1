"""Stand-ins shared by the HBNI filter, temper and macro-observation tests."""

from __future__ import annotations

import torch

DT = torch.float64
THETA = torch.tensor([1.0, 6.0, 20.0], dtype=DT)
"""The toy's noise levels: class 0 noisy, class 2 nearly clean."""


class DrawsPosterior:
    """Minimal stand-in with the surface HBNIFilter uses: fixed theta draws ``(S, M)`` and a class prior."""

    def __init__(self, draws, class_prior=None):
        self._draws = torch.as_tensor(draws, dtype=DT)
        self.num_classes = self._draws.shape[1]
        self.class_prior = (
            torch.full((self.num_classes,), 1 / self.num_classes, dtype=DT) if class_prior is None else class_prior
        )

    def theta_draws(self):
        return self._draws
