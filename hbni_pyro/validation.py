"""Checks and normalisation for classifier outputs at the public boundary.

A classifier output is a point on the probability simplex: ``M >= 2`` entries, each
``>= 0``, summing to 1. Classifiers emit exact zeros (float32 softmax underflow), and
``log 0`` must never reach a sum, so entries are clamped to :data:`OUTPUT_FLOOR` and
each row is renormalised. Anything else that is off the simplex is rejected with a
``ValueError`` naming the first offending row. Tensors stay on their device; ``meta`` tensors
(shapes only) pass the shape checks and skip the value checks.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from hbni_infra.checks import first_difference

OUTPUT_FLOOR: float = 1e-6
"""Smallest probability an output entry may take after clamping (before renormalising)."""

SIMPLEX_ATOL: float = 1e-3
"""Largest tolerated ``|sum(o) - 1|`` for an output row before it is rejected."""

DTYPE = torch.float64
"""All noise-model arithmetic runs in double precision."""


def _row_name(flat_index: int, batch_shape: torch.Size) -> str:
    """How a message names a bad row: ``"the output"`` for a single row, else its index."""
    if len(batch_shape) == 0:
        return "the output"
    if len(batch_shape) == 1:
        return f"row {flat_index}"
    idx = []
    for size in reversed(batch_shape):
        idx.append(flat_index % size)
        flat_index //= size
    return "row " + str(tuple(reversed(idx)))


def as_outputs(obs: Any, num_classes: int | None = None, *, name: str = "obs", min_dim: int = 1) -> Tensor:
    """Validate classifier outputs and return them floored, renormalised, as float64.

    Args:
        obs: array-like of shape ``(..., M)``; each row a probability vector.
        num_classes: expected ``M``; ``None`` accepts any ``M >= 2``.
        name: argument name used in error messages.
        min_dim: minimum number of dimensions (1 for one output, 2 for a batch of rows).

    Returns:
        float64 tensor of the same shape with every entry ``>= OUTPUT_FLOOR / (1 + M * OUTPUT_FLOOR)``
        and every row summing to 1.

    Raises:
        TypeError: ``obs`` is not numeric.
        ValueError: wrong shape or width, NaN/inf, negative entries, or a row sum off 1
            by more than :data:`SIMPLEX_ATOL`; the message names the first bad row.
    """
    try:
        x = torch.as_tensor(obs)
        if isinstance(obs, (list, tuple)) and x.is_floating_point():
            x = torch.as_tensor(obs, dtype=DTYPE)  # read Python floats straight into float64
    except (TypeError, ValueError, RuntimeError) as exc:
        raise TypeError(f"{name}: expected a numeric array of probability rows, got {type(obs).__name__}") from exc
    if x.dtype == torch.bool or x.is_complex() or not (x.is_floating_point() or x.dtype in _INT_DTYPES):
        raise TypeError(f"{name}: expected a real floating-point array, got dtype {x.dtype}")
    x = x.to(DTYPE)
    if x.dim() < min_dim:
        raise ValueError(f"{name}: expected at least {min_dim} dimension(s) (..., M), got shape {tuple(x.shape)}")
    if x.dim() == 0 or x.shape[-1] < 2:
        raise ValueError(f"{name}: expected rows of M >= 2 class probabilities, got shape {tuple(x.shape)}")
    if num_classes is not None and x.shape[-1] != num_classes:
        raise ValueError(f"{name}: expected rows of width M = {num_classes}, got width {x.shape[-1]}")
    if x.numel() == 0:
        raise ValueError(f"{name}: expected at least one output row, got shape {tuple(x.shape)}")
    rows = x.reshape(-1, x.shape[-1])
    if has_values(rows):
        _check_rows(rows, x.shape[:-1], name)
    rows = rows.clamp_min(OUTPUT_FLOOR)
    rows = rows / rows.sum(-1, keepdim=True)
    return rows.reshape(x.shape)


def _check_rows(rows: Tensor, batch_shape: torch.Size, name: str) -> None:
    """Raise ``ValueError`` naming the first row ``(R, M)`` off the simplex (one host sync when all are on it)."""
    non_finite = ~torch.isfinite(rows).all(-1)
    negative = (rows < 0).any(-1)
    off_sum = (rows.sum(-1) - 1).abs() > SIMPLEX_ATOL
    if not (non_finite | negative | off_sum).any():
        return
    if non_finite.any():
        raise ValueError(f"{name}: {_row_name(int(non_finite.nonzero()[0]), batch_shape)} contains NaN or inf")
    if negative.any():
        raise ValueError(f"{name}: {_row_name(int(negative.nonzero()[0]), batch_shape)} has a negative entry")
    i = int(off_sum.nonzero()[0])
    raise ValueError(
        f"{name}: {_row_name(i, batch_shape)} sums to {float(rows[i].sum()):.6g}, "
        f"expected 1 within {SIMPLEX_ATOL} (a probability vector)"
    )


def has_values(x: Tensor) -> bool:
    """Whether ``x`` holds values: ``meta`` tensors carry shapes only, so value checks skip them."""
    return x.device.type != "meta"


_INT_DTYPES = (torch.uint8, torch.int8, torch.int16, torch.int32, torch.int64)


def as_labels(labels: Any, num_obs: int, num_classes: int, *, name: str = "labels") -> Tensor:
    """Validate class labels: int64 tensor ``(N,)`` with entries in ``[0, M)`` or ``-1`` (unknown)."""
    try:
        x = torch.as_tensor(labels)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError(
            f"{name}: expected integer class indices of shape ({num_obs},), got {type(labels).__name__}"
        ) from None
    if x.is_floating_point():
        if has_values(x) and not torch.equal(x, x.round()):
            raise TypeError(f"{name}: expected integer class indices, got non-integer values")
    elif x.dtype not in _INT_DTYPES:
        raise TypeError(f"{name}: expected integer class indices, got dtype {x.dtype}")
    x = x.to(torch.long)
    if x.shape != (num_obs,):
        raise ValueError(f"{name}: expected shape ({num_obs},) to match obs, got {tuple(x.shape)}")
    bad = (x < -1) | (x >= num_classes)
    if has_values(x) and bad.any():
        i = int(bad.nonzero()[0])
        raise ValueError(f"{name}: entry {i} is {int(x[i])}, expected a class in [0, {num_classes}) or -1 for unknown")
    return x


def as_class_prior(prior: Any, num_classes: int, *, name: str = "class_prior") -> Tensor:
    """Validate a class prior ``p`` (``None`` means uniform); float64 ``(M,)`` summing to 1, all > 0."""
    if prior is None:
        return torch.full((num_classes,), 1.0 / num_classes, dtype=DTYPE)
    p = torch.as_tensor(prior, dtype=DTYPE)
    if p.shape != (num_classes,):
        raise ValueError(f"{name}: expected shape ({num_classes},), got {tuple(p.shape)}")
    if has_values(p):
        if not torch.isfinite(p).all() or (p <= 0).any():
            raise ValueError(f"{name}: expected strictly positive finite entries, got {p.tolist()}")
        if abs(float(p.sum()) - 1) > SIMPLEX_ATOL:
            raise ValueError(f"{name}: expected entries summing to 1, got sum {float(p.sum()):.6g}")
    return p / p.sum()


def as_sequence_ids(ids: Any, num_obs: int, *, name: str = "sequence_ids") -> Tensor:
    """Validate sequence ids ``(N,)`` (non-negative integers) and renumber them ``0..K-1`` in order of first id."""
    x = torch.as_tensor(ids)
    if x.is_floating_point() or x.dtype not in _INT_DTYPES:
        raise TypeError(f"{name}: expected integer sequence ids, got dtype {x.dtype}")
    if x.shape != (num_obs,):
        raise ValueError(f"{name}: expected shape ({num_obs},) to match obs, got {tuple(x.shape)}")
    if (x < 0).any():
        raise ValueError(f"{name}: entry {int((x < 0).nonzero()[0])} is negative, expected ids >= 0")
    return torch.unique(x.long(), return_inverse=True)[1]


def check_same_classes(expected: tuple[str, ...] | None, got: Any, what: str, name: str = "classes") -> None:
    """Raise ``ValueError`` naming the difference unless the class names ``got`` are ``expected`` (in that order);
    nothing to check when ``expected`` is ``None``."""
    if expected is None:
        return
    got = tuple(got)
    if got != expected:
        raise ValueError(
            f"{name}: expected the classes of {what} in its order {list(expected)}, got {list(got)} "
            f"(first difference at column {first_difference(expected, got)})"
        )
