"""The MH machinery the noise models' kernels share, runnable by ``pyro.infer.MCMC``.

- :mod:`.base`: :class:`BatchedKernel`, the ``MCMCKernel`` protocol over many chains in one tensor program (the
  datasets x chains layout, step-size adaptation in warm-up, acceptance bookkeeping), and its random walks.
- :mod:`.class_moves`: the class move of the frame-level models (the paper's and the confusion-aware one),
  their state and data (:class:`FrameData`), compiled on the CPU by :mod:`.class_move_numba`;
  :mod:`.hyper_move`: their move of ``(kappa, gamma)``.

Each model's own kernel and steps live in its room (:mod:`hbni_pyro.models`).
"""

from hbni_pyro.mcmc.base import AdaptiveWalk, AdaptiveWalk2D, BatchedKernel, flatten_chains, fraction
from hbni_pyro.mcmc.hyper_move import update_hyper
from hbni_pyro.mcmc.class_moves import (
    FrameData,
    MHData,
    MHState,
    alias_draw,
    alias_tables,
    frame_data,
    sufficient_stats,
    update_classes,
)

__all__ = [
    "AdaptiveWalk",
    "AdaptiveWalk2D",
    "BatchedKernel",
    "FrameData",
    "MHData",
    "MHState",
    "alias_draw",
    "alias_tables",
    "flatten_chains",
    "fraction",
    "frame_data",
    "sufficient_stats",
    "update_classes",
    "update_hyper",
]
