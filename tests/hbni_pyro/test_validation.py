"""Output validation at the public boundary: floors for exact zeros, clear errors for bad rows."""

import pytest
import torch

from hbni_pyro import OUTPUT_FLOOR, as_outputs
from hbni_pyro.validation import SIMPLEX_ATOL, as_class_prior


def test_exact_zeros_are_floored_and_rows_renormalised():
    x = as_outputs([[1.0, 0.0, 0.0], [0.25, 0.25, 0.5]])
    assert x.dtype == torch.float64
    assert (x > 0).all() and torch.isfinite(x.log()).all()
    torch.testing.assert_close(x.sum(-1), torch.ones(2, dtype=torch.float64))
    assert x[0, 1].item() == pytest.approx(OUTPUT_FLOOR / (1 + 2 * OUTPUT_FLOOR))
    torch.testing.assert_close(x[1], torch.tensor([0.25, 0.25, 0.5], dtype=torch.float64))


def test_rows_within_tolerance_are_accepted_and_renormalised():
    x = as_outputs([[0.5, 0.5 + SIMPLEX_ATOL / 2]])
    torch.testing.assert_close(x.sum(-1), torch.ones(1, dtype=torch.float64))


def test_batched_rows_are_named_by_index_tuple():
    bad = torch.full((2, 4, 3), 1 / 3)
    bad[1, 3, 0] = -0.1
    with pytest.raises(ValueError, match=r"obs: row \(1, 3\) has a negative entry"):
        as_outputs(bad)


@pytest.mark.parametrize(
    "value, kwargs, error, match",
    [
        ([[0.5, 0.5]], {"num_classes": 3}, ValueError, "width M = 3"),
        (torch.zeros(0, 3), {}, ValueError, "at least one output row"),
        ([[True, False]], {}, TypeError, "floating-point"),
        (object(), {}, TypeError, "numeric array"),
    ],
)
def test_bad_outputs(value, kwargs, error, match):
    with pytest.raises(error, match=match):
        as_outputs(value, **kwargs)


def test_class_prior():
    torch.testing.assert_close(as_class_prior(None, 4), torch.full((4,), 0.25, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"class_prior: expected shape \(3,\)"):
        as_class_prior([0.5, 0.5], 3)
    with pytest.raises(ValueError, match="strictly positive"):
        as_class_prior([1.0, 0.0], 2)
    with pytest.raises(ValueError, match="summing to 1"):
        as_class_prior([0.3, 0.3], 2)
