"""Errors at hbni_pyro's public boundary name the argument; numpy and torch scalars count as numbers."""

import math

import numpy as np
import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_outputs

THETA = torch.tensor([1.0, 6.0, 20.0], dtype=torch.float64)


def _outputs(n: int = 9, seed: int = 0) -> torch.Tensor:
    return sample_outputs(THETA, torch.arange(3).repeat_interleave(n // 3), torch.Generator().manual_seed(seed))


def test_a_numpy_threshold_and_frame_budget_are_accepted():
    process = hbni_pyro.MacroObservationProcess(
        hbni_pyro.StaticStateBayesFilter(3), threshold=np.float32(0.9), max_frames=np.int64(7)
    )
    assert math.isclose(process.threshold, 0.9, rel_tol=1e-6) and process.max_frames == 7
    assert hbni_pyro.MacroObservationProcess(
        hbni_pyro.StaticStateBayesFilter(3), threshold=torch.tensor(0.95)
    ).threshold == pytest.approx(0.95)
    with pytest.raises(ValueError, match=r"threshold: expected a finite number in \(0, 1\], got 1.5"):
        hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=np.float64(1.5))
    with pytest.raises(TypeError, match="max_frames: expected an int"):
        hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), max_frames=2.5)


def test_a_bad_frame_is_named_by_its_place_in_the_stream():
    stream = _outputs(6)
    stream[2, 0] = float("nan")
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=1.0, max_frames=6)
    with pytest.raises(ValueError, match=r"o \(frame 3 of the stream\): the output contains NaN or inf"):
        process.run(stream)


def test_fit_names_a_bad_seed_and_bad_labels():
    x = _outputs()
    with pytest.raises(TypeError, match=r"seed: expected an int, got None"):
        hbni_pyro.fit(x, seed=None, num_samples=5, warmup_steps=5, progress=False)
    with pytest.raises(TypeError, match=r"labels: expected integer class indices of shape \(9,\), got str"):
        hbni_pyro.fit(x, labels="abc", num_samples=5, warmup_steps=5, progress=False)
    with pytest.raises(ValueError, match=r"num_samples: expected an int >= 1, got 0"):
        hbni_pyro.fit(x, num_samples=np.int64(0), progress=False)


def test_fit_accepts_numpy_and_torch_integers():
    x = _outputs()
    a = hbni_pyro.fit(
        x,
        num_chains=np.int64(2),
        num_samples=np.int32(20),
        warmup_steps=torch.tensor(10),
        seed=np.int64(3),
        progress=False,
    )
    b = hbni_pyro.fit(x, num_chains=2, num_samples=20, warmup_steps=10, seed=3, progress=False)
    assert torch.equal(a.samples["theta"], b.samples["theta"])
