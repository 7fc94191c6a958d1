"""Boundary checks accept Python, numpy and 0-d torch numbers and name the argument when they refuse."""

import math

import numpy as np
import pytest
import torch

from hbni_infra.checks import as_choice, as_device, as_float, as_int, as_names, as_probability, first_difference


@pytest.mark.parametrize("value", [3, np.int64(3), np.int32(3), torch.tensor(3)])
def test_ints(value):
    assert as_int("n", value, minimum=1) == 3 and type(as_int("n", value)) is int


@pytest.mark.parametrize("value", [0.9, np.float32(0.9), np.float64(0.9), torch.tensor(0.9), 1])
def test_floats(value):
    out = as_probability("threshold", value)
    assert type(out) is float and math.isclose(out, float(value), rel_tol=1e-6)


@pytest.mark.parametrize("value", [True, "3", 3.0, None, torch.tensor([3])])
def test_non_ints_are_type_errors(value):
    with pytest.raises(TypeError, match="n: expected an int"):
        as_int("n", value)


@pytest.mark.parametrize("value", [True, "0.1", None, [0.1]])
def test_non_numbers_are_type_errors(value):
    with pytest.raises(TypeError, match="alpha: expected a number"):
        as_float("alpha", value)


def test_ranges_name_the_argument_and_interval():
    with pytest.raises(ValueError, match=r"n: expected an int >= 1, got 0"):
        as_int("n", 0, minimum=1)
    with pytest.raises(ValueError, match=r"threshold: expected a finite number in \(0, 1\], got 0.0"):
        as_probability("threshold", 0.0, allow_zero=False)
    with pytest.raises(ValueError, match=r"p: expected a finite number in \[0, 1\], got nan"):
        as_probability("p", float("nan"))
    with pytest.raises(ValueError, match=r"x: expected a finite number in \[-inf, inf\], got inf"):
        as_float("x", math.inf)
    assert as_float("x", 2.0, 0.0, 2.0) == 2.0
    with pytest.raises(ValueError, match=r"\[0, 2\)"):
        as_float("x", 2.0, 0.0, 2.0, high_open=True)


def test_names_and_their_first_difference():
    assert as_names("obs_names", ["a", "b"], 2) == ("a", "b") and as_names("obs_names", None, 2) is None
    assert as_names("action_names", ("a", "b", "c"), 2, at_least=True) == ("a", "b", "c")
    with pytest.raises(ValueError, match=r"obs_names: expected 2 distinct names, got \['a', 'a'\]"):
        as_names("obs_names", ["a", "a"], 2)
    with pytest.raises(ValueError, match="action_names: expected at least 3 distinct names"):
        as_names("action_names", ["a", "b"], 3, at_least=True)
    with pytest.raises(TypeError, match="class_names: expected a sequence of names, got str"):
        as_names("class_names", "abc", 3)
    assert first_difference("abc", "abd") == 2 and first_difference("ab", "abc") == 2 and first_difference("", "x") == 0


def test_devices_are_parsed_and_probed():
    assert as_device("device", "cpu") == torch.device("cpu")
    assert as_device("device", torch.device("meta")).type == "meta"
    with pytest.raises(TypeError, match="device: expected a str or torch.device, got 0"):
        as_device("device", 0)
    with pytest.raises(ValueError, match="device: expected a torch device .* got 'gpu0'"):
        as_device("device", "gpu0")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: device 'cuda' is not available here"):
            as_device("device", "cuda")


def test_choices_name_the_argument_and_list_the_choices():
    assert as_choice("mode", "plugin", ("marginal", "plugin")) == "plugin"
    assert as_choice("k", 2, range(3)) == 2
    with pytest.raises(ValueError, match=r"mode: expected one of \['marginal', 'plugin'\], got 'mean'"):
        as_choice("mode", "mean", ("marginal", "plugin"))
