"""tabulate: macro-observation tables from recorded streams, checked by hand and against characterize."""

import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_outputs, tabulate


def test_tabulate_counts_by_hand():
    # Two classes; SSBF on confident outputs crosses 0.95 after a known number of frames.
    strong0 = torch.tensor([0.99, 0.01]).expand(3, 2)
    weak1 = torch.tensor([0.3, 0.7]).expand(3, 2)
    streams = torch.stack([strong0, weak1, weak1])
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(2), threshold=0.95, max_frames=3)
    model = tabulate(process, streams, torch.tensor([0, 1, 0]))
    # StaticStateBayesFilter(0.7 / 0.3 per frame): posterior on class 1 after k frames = 0.7^k / (0.7^k + 0.3^k):
    # 0.7, 0.845, 0.927 -> never reaches 0.95 in 3 frames: timed out, label 1, frames 3.
    torch.testing.assert_close(model.confusion, torch.tensor([[0.5, 0.5], [0.0, 1.0]], dtype=torch.float64))
    assert model.joint[0, 0, 0] == 0.5 and model.joint[0, 1, 2] == 0.5 and model.joint[1, 1, 2] == 1.0
    torch.testing.assert_close(model.timed_out, torch.tensor([0.5, 1.0], dtype=torch.float64))
    assert model.info["generative"] == "recorded streams" and model.info["num_streams"] == 3


def test_tabulate_agrees_with_characterize_on_simulated_streams():
    """On streams drawn from a known theta, the recorded-stream table matches the simulated one
    within 5 binomial standard errors per confusion cell."""
    theta = torch.tensor([1.0, 6.0, 20.0])
    n = 3000
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.95, max_frames=10)
    truth = torch.arange(3).repeat_interleave(n)
    streams = sample_outputs(theta, truth.unsqueeze(-1).expand(-1, 10), torch.Generator().manual_seed(1))
    recorded = tabulate(process, streams, truth)
    simulated = hbni_pyro.characterize(process, theta, n, seed=2)
    p = simulated.confusion
    se = (p * (1 - p) * 2 / n).sqrt().clamp_min(1 / n)
    assert ((recorded.confusion - p).abs() < 5 * se).all()


def test_tabulate_errors():
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(2), threshold=0.9, max_frames=2)
    streams = torch.full((2, 2, 2), 0.5)
    with pytest.raises(ValueError, match="missing \\[1\\]"):
        tabulate(process, streams, torch.tensor([0, 0]))
    with pytest.raises(ValueError, match="expected 2 entries"):
        tabulate(process, streams, torch.tensor([0, 1, 1]))
    with pytest.raises(TypeError, match="true_class"):
        tabulate(process, streams, torch.tensor([0.0, 1.0]))
    with pytest.raises(TypeError, match="process"):
        tabulate("ssbf", streams, torch.tensor([0, 1]))
    with pytest.raises(ValueError, match=r"true_class: 9 is out of range: expected classes in \[0, 2\)"):
        tabulate(process, streams, torch.tensor([0, 9]))
