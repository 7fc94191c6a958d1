"""Averaging a noise model's evidence over posterior draws: in log space, summed in a fixed order, in chunks.

Every evidence class (:attr:`hbni_pyro.NoiseModel.evidence`) computes ``log mean_s p(o_1:n | c, draw s)`` for
blocks of outputs; the terms of a chunk of blocks are built at once and reduced over the draws by
:func:`logsumexp_in_order`, so that one stream and a batch of streams agree exactly.
"""

from __future__ import annotations

from torch import Tensor

CHUNK_ELEMENTS = 1 << 16
"""Largest number of (block, class, draw) terms built at once (512 KiB of doubles, so each chunk's
passes stay in cache)."""


def logsumexp_in_order(x: Tensor) -> Tensor:
    """``logsumexp`` over the last dim, summing in index order whatever the batch shape.

    ``torch.logsumexp`` may split a reduction across threads differently for different batch
    sizes; ``cumsum`` always adds in order, so one stream and a batch of streams agree exactly.
    """
    top = x.amax(-1, keepdim=True)
    # Terms below exp(-700) cannot change a sum that is >= 1; clamping them keeps exp and the
    # sum off the slow subnormal path.
    return top.squeeze(-1) + (x - top).clamp_min_(-700.0).exp_().cumsum(-1)[..., -1].log()


def chunks(num_rows: int, per_row: int) -> range:
    """Starts of the chunks of ``num_rows`` rows of ``per_row`` terms each, at most :data:`CHUNK_ELEMENTS` terms a
    chunk (at least one row)."""
    return range(0, num_rows, max(1, CHUNK_ELEMENTS // per_row))
