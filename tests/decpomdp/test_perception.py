"""PerfectPerception and the PerceptionModel protocol."""

import pytest
import torch

from decpomdp.perception import PerceptionModel, PerfectPerception


def test_perfect_perception_reports_the_true_class_and_fixed_frames():
    model = PerfectPerception(6, frames=4)
    truth = torch.tensor([0, 5, 3, 3, 1])
    generator = torch.Generator().manual_seed(0)
    state = generator.get_state()
    label, frames = model.sample(truth, generator)
    assert torch.equal(label, truth) and label.dtype == torch.long
    assert torch.equal(frames, torch.full((5,), 4)) and frames.dtype == torch.long
    assert torch.equal(generator.get_state(), state)  # consumes no randomness
    label[0] = 2
    assert truth[0] == 0  # returns a copy
    assert PerfectPerception(3).sample(torch.zeros(0, dtype=torch.long), generator)[0].shape == (0,)


def test_satisfies_the_protocol():
    assert isinstance(PerfectPerception(2), PerceptionModel)
    assert not isinstance(object(), PerceptionModel)


@pytest.mark.parametrize(
    "args, error, match",
    [
        ((0,), ValueError, "num_classes"),
        ((2.0,), TypeError, "num_classes"),
        ((2, 0), ValueError, "frames"),
        ((True,), TypeError, "num_classes"),
        ((2, 1.5), TypeError, "frames"),
    ],
)
def test_bad_constructor_arguments(args, error, match):
    with pytest.raises(error, match=match):
        PerfectPerception(*args)


def test_bad_true_class():
    model, generator = PerfectPerception(3), torch.Generator()
    with pytest.raises(TypeError, match="true_class"):
        model.sample(torch.tensor([0.0]), generator)
    with pytest.raises(TypeError, match="true_class"):
        model.sample([0, 1], generator)
    with pytest.raises(ValueError, match="true_class"):
        model.sample(torch.tensor([[0]]), generator)
    with pytest.raises(ValueError, match=r"\[0, 3\)"):
        model.sample(torch.tensor([3]), generator)
    with pytest.raises(ValueError, match=r"\[0, 3\)"):
        model.sample(torch.tensor([-1]), generator)
