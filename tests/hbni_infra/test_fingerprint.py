"""Fingerprints: stable digests, and a check that names the first field that differs."""

import numpy as np
import pytest
import torch

from hbni_infra.fingerprint import check_fingerprint, digest


def test_digest_is_stable_and_sensitive():
    t = torch.arange(6, dtype=torch.float64).view(2, 3)
    assert digest(t, {"a": 1}) == digest(t.clone(), {"a": 1})
    assert digest({"a": 1, "b": 2}) == digest({"b": 2, "a": 1})
    different = [
        digest(t.view(3, 2)),
        digest(t.float()),
        digest(t + 1e-12),
        digest(t, {"a": 2}),
        digest(t.numpy()),
        digest(b"x"),
        digest("x"),
    ]
    assert len({digest(t), *different}) == len(different) + 1
    assert digest(np.zeros(0)) == digest(np.zeros(0))


def test_equal_fingerprints_pass():
    check_fingerprint(
        {"seed": 0, "cfg": {"alpha": 0.1, "sizes": (2, 3)}},
        {"cfg": {"sizes": [2, 3], "alpha": 0.1}, "seed": 0},
        "checkpoint",
    )


@pytest.mark.parametrize(
    "recorded, expected, field",
    [
        ({"seed": 0}, {"seed": 7}, "seed"),
        ({"cfg": {"alpha": 0.1, "n": 3}}, {"cfg": {"alpha": 0.2, "n": 3}}, "cfg.alpha"),
        ({"problem": "a"}, {"problem": "a", "horizon": 4}, "horizon"),
        ({"problem": "a", "horizon": 3}, {"problem": "a"}, "horizon"),
    ],
)
def test_a_difference_names_the_field(recorded, expected, field):
    with pytest.raises(ValueError, match=rf"checkpoint 'x.ckpt' was written by another run: {field} was .* here"):
        check_fingerprint(recorded, expected, "checkpoint", "x.ckpt")


def test_no_recorded_fingerprint_is_refused():
    with pytest.raises(ValueError, match="cache records no fingerprint"):
        check_fingerprint(None, {"seed": 0}, "cache")
